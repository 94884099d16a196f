#include "cdpr/controller/supervisor.hpp"

#include <gtest/gtest.h>

#include <fstream>
#include <initializer_list>
#include <iterator>
#include <set>
#include <sstream>
#include <utility>
#include <vector>

namespace cdpr::controller {
namespace {

using S = DaemonState;
using E = SupervisorEvent;
using A = SupervisorAction;

constexpr S kAllStates[] = {
    S::kStarting,           S::kHolding,  S::kMoving, S::kMeasuring, S::kIdentifying,
    S::kAwaitingAcceptance, S::kApplying, S::kFault,  S::kStopped,   S::kDisabled};
constexpr E kAllEvents[] = {E::kBoot,
                            E::kStartFailed,
                            E::kStarted,
                            E::kStartedDisabled,
                            E::kEnabled,
                            E::kDisable,
                            E::kHomed,
                            E::kMoveRequested,
                            E::kRtMoving,
                            E::kRtHolding,
                            E::kCalibrationStarted,
                            E::kMeasured,
                            E::kMorePoses,
                            E::kIdentified,
                            E::kCalibrationEnded,
                            E::kRejected,
                            E::kApply,
                            E::kApplyFailed,
                            E::kApplied,
                            E::kFaultLatched,
                            E::kFaultCleared,
                            E::kFaultResetFailed};

// Fires `events` in order from `from`; expects each to be accepted; returns the last transition.
Transition run(S from, std::initializer_list<E> events) {
  Supervisor s(from);
  Transition t;
  for (E e : events) {
    t = s.fire(e);
    EXPECT_TRUE(t.accepted) << t.refusal;
  }
  EXPECT_EQ(s.state(), t.to);
  return t;
}

TEST(Supervisor, StartsInStartingAndHoldsAfterStartUp) {
  Supervisor s;
  EXPECT_EQ(s.state(), S::kStarting);
  EXPECT_EQ(run(S::kStarting, {E::kBoot, E::kStarted}).to, S::kHolding);
  EXPECT_EQ(run(S::kStarting, {E::kBoot, E::kStartFailed}).to, S::kFault);
}

TEST(Supervisor, StartsDisabledUntilTheOperatorEnablesAndDisablesOnlyWhileHolding) {
  EXPECT_EQ(run(S::kStarting, {E::kBoot, E::kStartedDisabled}).to, S::kDisabled);
  EXPECT_EQ(run(S::kDisabled, {E::kHomed, E::kEnabled, E::kHomed, E::kDisable}).to, S::kDisabled);
  Supervisor moving(S::kMoving);
  EXPECT_FALSE(moving.fire(E::kDisable).accepted);
  Supervisor disabled(S::kDisabled);
  EXPECT_FALSE(disabled.fire(E::kMoveRequested).accepted);
}

TEST(Supervisor, MovesAndHoldsAsTheRtLoopDoes) {
  EXPECT_EQ(run(S::kHolding, {E::kMoveRequested}).to, S::kMoving);
  EXPECT_EQ(run(S::kHolding, {E::kRtMoving, E::kRtMoving}).to, S::kMoving);
  EXPECT_EQ(run(S::kMoving, {E::kRtHolding, E::kRtHolding}).to, S::kHolding);
}

TEST(Supervisor, RunsACalibrationToAcceptanceAndTheHotSwap) {
  const Transition identified = run(S::kHolding, {E::kCalibrationStarted, E::kMeasured,
                                                  E::kMorePoses, E::kMeasured, E::kIdentified});
  EXPECT_EQ(identified.to, S::kAwaitingAcceptance);
  EXPECT_EQ(identified.action, A::kReleaseWorker);
  EXPECT_EQ(run(S::kAwaitingAcceptance, {E::kApply, E::kApplied}).to, S::kHolding);
  EXPECT_EQ(run(S::kAwaitingAcceptance, {E::kRejected}).to, S::kHolding);
  EXPECT_EQ(run(S::kAwaitingAcceptance, {E::kApplyFailed}).to, S::kHolding);
  EXPECT_EQ(run(S::kHolding, {E::kApply}).to, S::kApplying);  // rollback
}

TEST(Supervisor, AnEndedSequenceReleasesTheWorkerAndHolds) {
  for (S from : {S::kMeasuring, S::kIdentifying, S::kFault}) {
    const Transition t = run(from, {E::kCalibrationEnded});
    EXPECT_EQ(t.to, S::kHolding) << to_string(from);
    EXPECT_EQ(t.action, A::kReleaseWorker) << to_string(from);
  }
}

TEST(Supervisor, AFaultLatchesFromEveryStateButStartingAndStopsTheSequence) {
  for (S from : kAllStates) {
    Supervisor s(from);
    const Transition t = s.fire(E::kFaultLatched);
    if (from == S::kStarting || from == S::kFault) {
      EXPECT_FALSE(t.accepted) << to_string(from);
      continue;
    }
    EXPECT_TRUE(t.accepted) << to_string(from);
    EXPECT_EQ(t.to, S::kFault);
    EXPECT_EQ(t.action, A::kStopSequence);
  }
  EXPECT_EQ(run(S::kFault, {E::kFaultResetFailed, E::kFaultCleared}).to, S::kHolding);
}

TEST(Supervisor, EveryRowIsTakenAndOnlyOneRowPerStateAndEvent) {
  std::set<std::pair<S, E>> seen;
  for (const SupervisorRow& r : supervisor_table()) {
    EXPECT_TRUE(seen.insert({r.from, r.event}).second)
        << "two rows for " << to_string(r.from) << " / " << to_string(r.event);
    Supervisor s(r.from);
    const Transition t = s.fire(r.event);
    EXPECT_TRUE(t.accepted);
    EXPECT_EQ(t.from, r.from);
    EXPECT_EQ(t.to, r.to);
    EXPECT_EQ(t.action, r.action);
    EXPECT_EQ(s.state(), r.to);
  }
  EXPECT_EQ(seen.size(), supervisor_table().size());
}

TEST(Supervisor, RefusesAnEventWithoutARowNamingTheEventAndTheStateAndStays) {
  int refused = 0;
  for (S from : kAllStates) {
    for (E e : kAllEvents) {
      if (Supervisor::find(from, e) != nullptr) continue;
      Supervisor s(from);
      const Transition t = s.fire(e);
      EXPECT_FALSE(t.accepted);
      EXPECT_EQ(s.state(), from);
      EXPECT_EQ(t.to, from);
      EXPECT_NE(t.refusal.find(std::string("'") + to_string(e) + "'"), std::string::npos)
          << t.refusal;
      EXPECT_NE(t.refusal.find(std::string("'") + to_string(from) + "'"), std::string::npos)
          << t.refusal;
      ++refused;
    }
  }
  EXPECT_EQ(refused, static_cast<int>(std::size(kAllStates) * std::size(kAllEvents) -
                                      supervisor_table().size()));
  // e.g. accepting while measuring, a calibration that starts while in fault
  EXPECT_FALSE(Supervisor(S::kMeasuring).fire(E::kApply).accepted);
  EXPECT_FALSE(Supervisor(S::kFault).fire(E::kCalibrationStarted).accepted);
}

TEST(Supervisor, NamesEveryOutcomeDistinctly) {
  std::set<std::string> names;
  for (CalibrationRunOutcome o :
       {CalibrationRunOutcome::kMeasuring, CalibrationRunOutcome::kAwaitingAcceptance,
        CalibrationRunOutcome::kApplying, CalibrationRunOutcome::kApplied,
        CalibrationRunOutcome::kRejected, CalibrationRunOutcome::kFailed,
        CalibrationRunOutcome::kAborted}) {
    EXPECT_STRNE(to_string(o), "?");
    names.insert(to_string(o));
  }
  EXPECT_EQ(names.size(), 7u);
}

TEST(Supervisor, ArchitectureDocShowsTheCodesTable) {
  std::ifstream in(std::string(CDPR_SOURCE_DIR) + "/docs/architecture.md");
  ASSERT_TRUE(in) << "docs/architecture.md";
  std::stringstream ss;
  ss << in.rdbuf();
  EXPECT_NE(ss.str().find(supervisor_table_markdown()), std::string::npos)
      << "docs/architecture.md must contain the supervisor table as the code has it:\n"
      << supervisor_table_markdown();
}

}  // namespace
}  // namespace cdpr::controller
