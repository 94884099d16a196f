#include "cdpr/controller/rt_thread.hpp"

#include <gtest/gtest.h>
#include <linux/capability.h>
#include <sched.h>
#include <sys/mman.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <optional>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "alloc_counter.hpp"

namespace cdpr::controller {
namespace {

using std::chrono::microseconds;
using std::chrono::milliseconds;
using std::chrono::nanoseconds;

constexpr nanoseconds kPeriod = milliseconds{4};

// ---------------------------------------------------------------------------------------------
// PeriodicTimer on a stepped clock

TEST(PeriodicTimer, WakesOnTheGridAndMeasuresLatencyAndCompute) {
  ManualLoopClock clock(milliseconds{100});
  clock.set_wake_latency(microseconds{50});
  PeriodicTimer timer(clock, kPeriod);
  timer.start();
  const Wake w0 = timer.wait_next();
  EXPECT_EQ(w0.nominal, milliseconds{100} + kPeriod);
  EXPECT_EQ(w0.now, w0.nominal + microseconds{50});
  EXPECT_EQ(w0.latency, microseconds{50});
  EXPECT_EQ(w0.cycle, 0u);
  EXPECT_EQ(w0.tick, 0u);
  EXPECT_EQ(w0.skipped, 0u);
  clock.advance(microseconds{900});  // compute
  const CycleEnd e0 = timer.end_cycle();
  EXPECT_EQ(e0.compute, microseconds{900});
  EXPECT_FALSE(e0.overrun);
  EXPECT_EQ(e0.next_wake, w0.nominal + kPeriod);

  clock.set_wake_latency(microseconds{120});
  const Wake w1 = timer.wait_next();
  EXPECT_EQ(w1.nominal, w0.nominal + kPeriod);
  EXPECT_EQ(w1.latency, microseconds{120});
  EXPECT_EQ(w1.cycle, 1u);
  EXPECT_EQ(w1.tick, 1u);
  clock.advance(microseconds{300});
  timer.wait_next();  // ends cycle 1 itself

  const CycleStats& s = timer.stats();
  EXPECT_EQ(s.cycles(), 2u);
  EXPECT_EQ(s.overruns(), 0u);
  EXPECT_EQ(s.wake_latency().min(), microseconds{50});
  EXPECT_EQ(s.wake_latency().max(), microseconds{120});
  EXPECT_EQ(s.compute().min(), microseconds{300});
  EXPECT_EQ(s.compute().max(), microseconds{900});
  EXPECT_EQ(clock.sleeps(), 3u);
}

TEST(PeriodicTimer, OverrunIsCountedAndTheGridSkipsTheMissedPeriods) {
  ManualLoopClock clock;
  const nanoseconds lat = microseconds{50};
  clock.set_wake_latency(lat);
  PeriodicTimer timer(clock, kPeriod);
  timer.start(kPeriod);  // grid: 4, 8, 12, ... ms

  Wake w = timer.wait_next();                // 4 ms
  clock.advance(kPeriod + milliseconds{1});  // ends 1.05 ms after the next wake time (8 ms)
  CycleEnd e = timer.end_cycle();
  EXPECT_TRUE(e.overrun);
  EXPECT_EQ(e.skipped, 1u);
  EXPECT_EQ(e.next_wake, w.nominal + 2 * kPeriod);  // 12 ms: not 8 ms (no catch-up)
  EXPECT_GT(e.next_wake, clock.now());

  w = timer.wait_next();
  EXPECT_EQ(w.nominal, milliseconds{12});
  EXPECT_EQ(w.skipped, 1u);
  EXPECT_EQ(w.cycle, 1u);
  EXPECT_EQ(w.tick, 2u);
  EXPECT_EQ(w.latency, lat);

  clock.advance(2 * kPeriod + milliseconds{1});  // ends at 21.05 ms: 16 and 20 ms are missed
  e = timer.end_cycle();
  EXPECT_TRUE(e.overrun);
  EXPECT_EQ(e.skipped, 2u);
  EXPECT_EQ(e.next_wake, milliseconds{24});

  w = timer.wait_next();
  EXPECT_EQ(w.nominal, milliseconds{24});
  EXPECT_EQ(w.tick, 5u);
  clock.advance(microseconds{10});
  timer.end_cycle();

  const CycleStatsSnapshot s = timer.stats().snapshot();
  EXPECT_EQ(s.cycles, 3u);
  EXPECT_EQ(s.overruns, 2u);
  EXPECT_EQ(s.skipped_periods, 3u);
  EXPECT_EQ(s.last_overrun_cycle, 1u);
  EXPECT_EQ(s.last_overrun_compute, 2 * kPeriod + milliseconds{1});
  EXPECT_EQ(s.wake_latency.max, lat);
}

TEST(PeriodicTimer, ComputeEndingExactlyAtTheNextWakeIsNoOverrun) {
  ManualLoopClock clock;
  PeriodicTimer timer(clock, kPeriod);
  timer.start(kPeriod);
  timer.wait_next();  // wakes at 4 ms exactly (no latency set)
  clock.advance(kPeriod);
  const CycleEnd e = timer.end_cycle();
  EXPECT_FALSE(e.overrun);
  EXPECT_EQ(e.next_wake, 2 * kPeriod);
  EXPECT_EQ(timer.stats().overruns(), 0u);
}

TEST(PeriodicTimer, LateWakeUpBeyondOnePeriodIsAnOverrunAndRealigns) {
  // user-mode-linux: the thread wakes 6 ms late with a 4 ms period.
  ManualLoopClock clock;
  clock.set_wake_latency(milliseconds{6});
  PeriodicTimer timer(clock, kPeriod);
  timer.start(kPeriod);
  const Wake w = timer.wait_next();
  EXPECT_EQ(w.latency, milliseconds{6});
  clock.advance(microseconds{100});
  const CycleEnd e = timer.end_cycle();  // ends at 10.1 ms, after 8 ms
  EXPECT_TRUE(e.overrun);
  EXPECT_EQ(e.skipped, 1u);
  EXPECT_EQ(e.next_wake, milliseconds{12});
}

TEST(PeriodicTimer, RandomLoadNeverCatchesUpInABurstAndStaysOnTheGrid) {
  ManualLoopClock clock(milliseconds{3});
  PeriodicTimer timer(clock, kPeriod);
  timer.start();
  const MonoTime origin = timer.next_wake();
  std::mt19937_64 rng(7);
  std::uniform_int_distribution<std::int64_t> latency_us(0, 9000), compute_us(0, 9000);
  MonoTime previous_end{0};
  std::uint64_t overruns = 0, skipped = 0;
  for (int i = 0; i < 2000; ++i) {
    clock.set_wake_latency(microseconds{latency_us(rng)});
    const Wake w = timer.wait_next();
    ASSERT_EQ((w.nominal - origin) % kPeriod, nanoseconds{0});  // on the grid
    ASSERT_EQ(w.nominal - origin, static_cast<std::int64_t>(w.tick) * kPeriod);
    ASSERT_GT(w.nominal, previous_end);  // every wake-up is after the previous compute
    ASSERT_EQ(w.latency, w.now - w.nominal);
    clock.advance(microseconds{compute_us(rng)});
    const CycleEnd e = timer.end_cycle();
    previous_end = clock.now();
    ASSERT_EQ(e.overrun, previous_end > w.nominal + kPeriod);
    ASSERT_GT(e.next_wake, previous_end);
    ASSERT_LE(e.next_wake - previous_end, kPeriod);  // the first grid point after the end
    overruns += e.overrun;
    skipped += e.skipped;
  }
  EXPECT_EQ(timer.stats().overruns(), overruns);
  EXPECT_EQ(timer.stats().skipped_periods(), skipped);
  EXPECT_GT(overruns, 0u);
  EXPECT_EQ(clock.sleeps(), 2000u);  // one sleep per cycle
}

TEST(PeriodicTimer, EndWithoutACycleRecordsNothing) {
  ManualLoopClock clock;
  PeriodicTimer timer(clock, kPeriod);
  const CycleEnd e = timer.end_cycle();
  EXPECT_FALSE(e.overrun);
  EXPECT_EQ(timer.stats().cycles(), 0u);
  const Wake w = timer.wait_next();  // starts the grid by itself
  EXPECT_EQ(w.nominal, kPeriod);
}

TEST(PeriodicTimer, PerCyclePathDoesNotAllocate) {
  ManualLoopClock clock;
  clock.set_wake_latency(microseconds{30});
  PeriodicTimer timer(clock, kPeriod);
  CycleStatsBoard board;
  timer.start();
  test::AllocationCounter count;
  for (int i = 0; i < 1000; ++i) {
    timer.wait_next();
    clock.advance(microseconds{(i * 37) % 6000});
    timer.end_cycle();
    board.publish(timer.stats());
  }
  EXPECT_EQ(count.allocations(), 0u);
  EXPECT_EQ(board.read().cycles, 1000u);
}

// ---------------------------------------------------------------------------------------------
// RtLoop

RtOptions quiet_options() {
  RtOptions o;
  o.priority = 0;  // the tests do not take a CPU away from the machine
  o.lock_memory = false;
  o.prefault_stack_bytes = 64 * 1024;
  o.prefault_heap_bytes = 0;
  return o;
}

// Models compute time on the stepped clock and checks the RT thread's allocations.
class ScriptedCycle final : public CycleHandler {
 public:
  ScriptedCycle(ManualLoopClock& clock, std::vector<nanoseconds> compute)
      : clock_(clock), compute_(std::move(compute)) {}
  void set_loop(RtLoop* loop) { loop_ = loop; }
  void cycle(const Wake& w) noexcept override {
    if (w.cycle == 0) counter_.emplace();
    wakes_[static_cast<std::size_t>(w.cycle)] = w;
    clock_.advance(compute_[static_cast<std::size_t>(w.cycle)]);
    if (w.cycle + 1 == compute_.size()) {
      allocations_ = counter_->allocations();
      loop_->request_stop();
      done_.store(true);
    }
  }
  const Wake& wake(std::size_t i) const { return wakes_[i]; }
  std::uint64_t allocations() const { return allocations_; }
  // Waits until the script's last cycle ran (a generous bound: a hang, not a slow machine, fails):
  // the loop must not be stopped before, or it ends early on a loaded machine.
  bool wait_done() const {
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    while (!done_.load()) {
      if (std::chrono::steady_clock::now() > until) return false;
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
    return true;
  }

 private:
  ManualLoopClock& clock_;
  std::vector<nanoseconds> compute_;
  std::array<Wake, 64> wakes_{};
  RtLoop* loop_ = nullptr;
  std::optional<test::AllocationCounter> counter_;
  std::uint64_t allocations_ = ~0ull;
  std::atomic<bool> done_{false};
};

TEST(RtLoop, RunsCyclesOnTheGridAndPublishesExactStatistics) {
  ManualLoopClock clock(milliseconds{1});
  clock.set_wake_latency(microseconds{40});
  RtOptions o = quiet_options();
  o.period = milliseconds{20};  // as under user-mode-linux
  std::vector<nanoseconds> compute(50, microseconds{500});
  compute[10] = milliseconds{25};  // one overrun: ends 5.04 ms after the next wake time
  ScriptedCycle handler(clock, compute);
  RtLoop loop(o, handler, clock);
  handler.set_loop(&loop);
  ASSERT_TRUE(loop.start().ok());
  ASSERT_TRUE(handler.wait_done());
  loop.stop();
  EXPECT_FALSE(loop.running());
  EXPECT_EQ(loop.cycles(), 50u);
  const CycleStatsSnapshot s = loop.stats();
  EXPECT_EQ(s.cycles, 50u);
  EXPECT_EQ(s.overruns, 1u);
  EXPECT_EQ(s.skipped_periods, 1u);  // 25.04 ms from wake-up: past one wake time, not two
  EXPECT_EQ(s.last_overrun_cycle, 10u);
  EXPECT_EQ(s.wake_latency.min, microseconds{40});
  EXPECT_EQ(s.wake_latency.max, microseconds{40});
  EXPECT_EQ(s.compute.max, milliseconds{25});
  EXPECT_EQ(s.compute.min, microseconds{500});
  EXPECT_EQ(handler.wake(11).nominal - handler.wake(10).nominal, 2 * o.period);
  EXPECT_EQ(handler.wake(11).skipped, 1u);
  EXPECT_EQ(handler.wake(49).tick, 50u);
  EXPECT_EQ(handler.allocations(), 0u);  // the RT thread, first to last cycle
  EXPECT_TRUE(loop.setup().warnings.empty() || loop.setup().user_mode_linux)
      << loop.setup().warnings.front();
}

TEST(RtLoop, StartRejectsInvalidOptionsWithTheFieldNamed) {
  ManualLoopClock clock;
  ScriptedCycle handler(clock, {microseconds{1}});
  RtOptions o = quiet_options();
  o.period = nanoseconds{0};
  RtLoop bad_period(o, handler, clock);
  const Status st = bad_period.start();
  EXPECT_EQ(st.code(), ErrorCode::kOutOfRange);
  EXPECT_NE(st.message().find("period"), std::string_view::npos) << st.message();

  o = quiet_options();
  o.priority = 120;
  RtLoop bad_priority(o, handler, clock);
  EXPECT_NE(bad_priority.start().message().find("priority 120"), std::string_view::npos);
  o = quiet_options();
  o.cpu = -2;
  RtLoop bad_cpu(o, handler, clock);
  EXPECT_NE(bad_cpu.start().message().find("cpu -2"), std::string_view::npos);
}

class CountingCycle final : public CycleHandler {
 public:
  void cycle(const Wake& w) noexcept override {
    last_nominal.store(w.nominal.count(), std::memory_order_relaxed);
    count.fetch_add(1, std::memory_order_relaxed);
  }
  std::atomic<std::int64_t> last_nominal{0};
  std::atomic<std::uint64_t> count{0};
};

TEST(RtLoop, RunsOnTheMonotonicClockUntilStopped) {
  CountingCycle handler;
  RtOptions o = quiet_options();
  o.period = milliseconds{1};
  RtLoop loop(o, handler);
  ASSERT_TRUE(loop.start().ok());
  EXPECT_TRUE(loop.running());
  EXPECT_EQ(loop.start().code(), ErrorCode::kFailedPrecondition);  // already running
  const auto t0 = std::chrono::steady_clock::now();
  while (loop.cycles() < 20 && std::chrono::steady_clock::now() - t0 < std::chrono::seconds(10)) {
    std::this_thread::sleep_for(milliseconds{2});
  }
  loop.stop();
  EXPECT_GE(loop.cycles(), 20u);
  EXPECT_EQ(loop.cycles(), handler.count.load());
  EXPECT_EQ(loop.stats().cycles, loop.cycles());
  // The nominal times are CLOCK_MONOTONIC, the base of steady_clock.
  const auto now = std::chrono::steady_clock::now().time_since_epoch();
  EXPECT_LE(nanoseconds{handler.last_nominal.load()}, now);
  EXPECT_GT(nanoseconds{handler.last_nominal.load()}, now - std::chrono::seconds(10));
  loop.stop();  // idempotent

  // A second run: the statistics start again, the cycle counter keeps counting.
  const std::uint64_t first_run = loop.cycles();
  ASSERT_TRUE(loop.start().ok());
  const auto t1 = std::chrono::steady_clock::now();
  while (loop.stats().cycles < 3 &&
         std::chrono::steady_clock::now() - t1 < std::chrono::seconds(10)) {
    std::this_thread::sleep_for(milliseconds{2});
  }
  loop.stop();
  EXPECT_EQ(loop.cycles(), first_run + loop.stats().cycles);
  EXPECT_EQ(loop.cycles(), handler.count.load());
}

// ---------------------------------------------------------------------------------------------
// prepare_realtime, run in a child process so the test process keeps its scheduling and memory

struct ChildSetup {
  RtSetup setup;
  int policy = -1;  // sched_getscheduler in the child after the set-up
  long slack = -1;  // PR_GET_TIMERSLACK in the child after the set-up
  std::string all_warnings;
};

// Runs `before` then prepare_realtime(options) in a forked child and returns what it got.
template <typename Before>
ChildSetup run_in_child(const RtOptions& options, Before before) {
  int fds[2];
  EXPECT_EQ(pipe(fds), 0);
  const pid_t pid = fork();
  if (pid == 0) {
    close(fds[0]);
    before();
    const RtSetup r = prepare_realtime(options);
    std::ostringstream out;
    out << r.fifo << ' ' << r.priority << ' ' << r.cpu << ' ' << r.memory_locked << ' '
        << r.stack_prefaulted << ' ' << r.heap_prefaulted << ' ' << r.user_mode_linux << ' '
        << sched_getscheduler(0) << ' ' << r.timer_slack_ns << ' '
        << prctl(PR_GET_TIMERSLACK, 0UL, 0UL, 0UL, 0UL) << '\n';
    for (const auto& w : r.warnings) out << w << '\n';
    const std::string s = out.str();
    std::size_t off = 0;
    while (off < s.size()) {
      const ssize_t n = write(fds[1], s.data() + off, s.size() - off);
      if (n <= 0) break;
      off += static_cast<std::size_t>(n);
    }
    _exit(0);
  }
  close(fds[1]);
  std::string text;
  char buf[4096];
  ssize_t n;
  while ((n = read(fds[0], buf, sizeof buf)) > 0) text.append(buf, static_cast<std::size_t>(n));
  close(fds[0]);
  int status = 0;
  waitpid(pid, &status, 0);
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << "child crashed: " << status;
  ChildSetup c;
  std::istringstream in(text);
  in >> c.setup.fifo >> c.setup.priority >> c.setup.cpu >> c.setup.memory_locked >>
      c.setup.stack_prefaulted >> c.setup.heap_prefaulted >> c.setup.user_mode_linux >> c.policy >>
      c.setup.timer_slack_ns >> c.slack;
  std::string line;
  std::getline(in, line);
  while (std::getline(in, line)) {
    c.setup.warnings.push_back(line);
    c.all_warnings += line + "\n";
  }
  return c;
}

// Removes capabilities from the effective and permitted sets of this process.
void drop_capabilities(std::initializer_list<int> caps) {
  __user_cap_header_struct hdr{_LINUX_CAPABILITY_VERSION_3, 0};
  __user_cap_data_struct data[2]{};
  if (syscall(SYS_capget, &hdr, data) != 0) _exit(3);
  for (int c : caps) {
    data[c / 32].effective &= ~(1u << (c % 32));
    data[c / 32].permitted &= ~(1u << (c % 32));
  }
  if (syscall(SYS_capset, &hdr, data) != 0) _exit(4);
}

bool contains(const std::string& s, const std::string& part) {
  return s.find(part) != std::string::npos;
}

TEST(PrepareRealtime, WithoutPrivilegesGivesWarningsThatSayHowToFixNotAFailure) {
  RtOptions o;  // defaults: FIFO 80, memory locked, pre-faulting
  o.prefault_heap_bytes = 4 * 1024 * 1024;
  const ChildSetup c = run_in_child(o, [] {
    drop_capabilities({CAP_SYS_NICE, CAP_IPC_LOCK});
    rlimit zero{0, 0};
    setrlimit(RLIMIT_RTPRIO, &zero);
    rlimit small{64 * 1024, 64 * 1024};
    setrlimit(RLIMIT_MEMLOCK, &small);
  });
  EXPECT_FALSE(c.setup.fifo);
  EXPECT_EQ(c.policy, SCHED_OTHER);
  EXPECT_FALSE(c.setup.memory_locked);
  EXPECT_TRUE(contains(c.all_warnings, "EPERM (Operation not permitted)")) << c.all_warnings;
  EXPECT_TRUE(contains(c.all_warnings, "RLIMIT_RTPRIO is 0")) << c.all_warnings;
  EXPECT_TRUE(contains(c.all_warnings, "LimitRTPRIO")) << c.all_warnings;
  EXPECT_TRUE(contains(c.all_warnings, "RLIMIT_MEMLOCK is 64 KiB")) << c.all_warnings;
  EXPECT_TRUE(contains(c.all_warnings, "LimitMEMLOCK=infinity")) << c.all_warnings;
  // What does not need privileges is still done.
  EXPECT_EQ(c.setup.stack_prefaulted, o.prefault_stack_bytes);
  EXPECT_EQ(c.setup.heap_prefaulted, o.prefault_heap_bytes);
}

TEST(PrepareRealtime, ReportsExactlyWhatItObtained) {
  // Whatever this machine allows: each item is either obtained (and really in effect) or has a
  // warning.
  RtOptions o;
  o.cpu = 0;
  const ChildSetup c = run_in_child(o, [] {});
  const RtSetup& r = c.setup;
  EXPECT_EQ(r.fifo, c.policy == SCHED_FIFO);
  // 1 ns as set, or 0 where the kernel gives SCHED_FIFO threads no slack at all.
  EXPECT_GE(r.timer_slack_ns, 0);
  EXPECT_LE(r.timer_slack_ns, 1);
  EXPECT_EQ(c.slack, r.timer_slack_ns);
  if (r.fifo) {
    EXPECT_EQ(r.priority, o.priority);
  } else {
    EXPECT_TRUE(contains(c.all_warnings, "SCHED_FIFO")) << c.all_warnings;
  }
  if (r.cpu != 0) {
    EXPECT_TRUE(contains(c.all_warnings, "CPU 0")) << c.all_warnings;
  }
  if (!r.memory_locked) {
    EXPECT_TRUE(contains(c.all_warnings, "lock")) << c.all_warnings;
  }
  if (r.stack_prefaulted != o.prefault_stack_bytes) {
    EXPECT_TRUE(contains(c.all_warnings, "stack")) << c.all_warnings;
  }
  if (r.heap_prefaulted != o.prefault_heap_bytes) {
    EXPECT_TRUE(contains(c.all_warnings, "heap")) << c.all_warnings;
  }
  EXPECT_EQ(r.warnings.empty(), r.fifo && r.cpu == 0 && r.memory_locked && !r.user_mode_linux &&
                                    r.stack_prefaulted == o.prefault_stack_bytes &&
                                    r.heap_prefaulted == o.prefault_heap_bytes)
      << c.all_warnings;
}

TEST(PrepareRealtime, ImpossibleCpuAndPriorityAreWarnings) {
  RtOptions o;
  o.priority = 150;  // outside SCHED_FIFO's range
  o.cpu = CPU_SETSIZE - 1;
  o.lock_memory = false;
  o.prefault_heap_bytes = 0;
  const ChildSetup c = run_in_child(o, [] {});
  EXPECT_FALSE(c.setup.fifo);
  EXPECT_EQ(c.setup.cpu, -1);
  EXPECT_TRUE(contains(c.all_warnings, "priority 150 is outside")) << c.all_warnings;
  EXPECT_TRUE(
      contains(c.all_warnings, "CPU " + std::to_string(CPU_SETSIZE - 1) + " does not exist"))
      << c.all_warnings;
}

TEST(PrepareRealtime, NormalSchedulerAskedForGivesNoWarning) {
  RtOptions o = quiet_options();
  const ChildSetup c = run_in_child(o, [] {});
  EXPECT_FALSE(c.setup.fifo);
  EXPECT_EQ(c.slack, 1);  // not the default 50 us
  EXPECT_EQ(c.setup.timer_slack_ns, 1);
  EXPECT_TRUE(c.setup.warnings.empty() || c.setup.user_mode_linux) << c.all_warnings;
  EXPECT_EQ(c.setup.stack_prefaulted, o.prefault_stack_bytes);
}

TEST(PrepareRealtime, StackPrefaultIsCappedToTheStackThatIsLeft) {
  RtOptions o = quiet_options();
  o.prefault_stack_bytes = 60u << 20;  // more than the 8 MiB default stack
  const ChildSetup c = run_in_child(o, [] {});
  EXPECT_LT(c.setup.stack_prefaulted, o.prefault_stack_bytes);
  EXPECT_GT(c.setup.stack_prefaulted, 0u);
  EXPECT_TRUE(contains(c.all_warnings, "stack has")) << c.all_warnings;
}

TEST(RtSetup, DescribeSaysWhatWasObtained) {
  RtSetup r;
  r.fifo = true;
  r.priority = 80;
  r.cpu = 1;
  r.memory_locked = true;
  r.stack_prefaulted = 256 * 1024;
  r.heap_prefaulted = 32u << 20;
  EXPECT_EQ(r.describe(),
            "SCHED_FIFO 80, CPU 1, memory locked, 256 KiB stack and 32 MiB heap pre-faulted");
  EXPECT_TRUE(r.complete());
  RtSetup n;
  EXPECT_EQ(n.describe(),
            "normal scheduler, not pinned, memory not locked, 0 bytes stack and 0 bytes heap "
            "pre-faulted");
}

}  // namespace
}  // namespace cdpr::controller
