// Wake-up latency of the RT loop (cdpr::controller::RtLoop: absolute clock_nanosleep on
// CLOCK_MONOTONIC) at 250 Hz, against a plain std::this_thread::sleep_until loop measured in the
// same run, on the same kind of thread, interleaved in rounds so both see the same machine load.
// Two passes: the normal scheduler, then SCHED_FIFO with locked memory where the system grants
// it (the output says what was obtained). Figures are printed, nothing is asserted.
//
//   rt_loop_bench [--seconds S] [--period-ms P] [--priority N] [--rounds R]
//     S: seconds per loop and pass (default 10), P: period (default 4 ms = 250 Hz),
//     N: SCHED_FIFO priority of pass 2 (default 80, as cdprd), R: rounds per pass (default 4)
#include <sys/utsname.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <string>
#include <thread>

#include "cdpr/controller/cycle_stats.hpp"
#include "cdpr/controller/rt_thread.hpp"

namespace {

using cdpr::controller::CycleHandler;
using cdpr::controller::DurationHistogram;
using cdpr::controller::DurationSummary;
using cdpr::controller::format_duration;
using cdpr::controller::prepare_realtime;
using cdpr::controller::RtLoop;
using cdpr::controller::RtOptions;
using cdpr::controller::RtSetup;
using cdpr::controller::summarize;
using cdpr::controller::Wake;
using std::chrono::nanoseconds;
using Clock = std::chrono::steady_clock;

struct Totals {
  DurationHistogram latency;
  std::uint64_t overruns = 0;
};

// The published snapshot is a summary; to merge the rounds, the cycle records the latency it is
// given into one histogram per pass (the RtLoop's own statistics see the same values).
class RecordingCycle final : public CycleHandler {
 public:
  explicit RecordingCycle(DurationHistogram& h) : h_(h) {}
  void cycle(const Wake& w) noexcept override { h_.record(w.latency); }

 private:
  DurationHistogram& h_;
};

RtSetup run_rt_loop(const RtOptions& o, nanoseconds duration, Totals& t) {
  RecordingCycle handler(t.latency);
  RtLoop loop(o, handler);
  if (const cdpr::Status st = loop.start(); !st) {
    std::fprintf(stderr, "RtLoop: %s\n", st.to_string().c_str());
    std::exit(1);
  }
  std::this_thread::sleep_for(duration);
  loop.stop();
  t.overruns += loop.stats().overruns;
  return loop.setup();
}

// The baseline: std::this_thread::sleep_until on steady_clock, next += period, on a thread set up
// like the RT loop's.
void run_sleep_until(const RtOptions& o, nanoseconds duration, Totals& t) {
  std::thread th([&] {
    prepare_realtime(o);
    const auto end = Clock::now() + duration;
    auto next = Clock::now() + o.period;
    while (next < end) {
      std::this_thread::sleep_until(next);
      const auto now = Clock::now();
      t.latency.record(now - next);
      next += o.period;
      if (now > next) ++t.overruns;  // woke after the following wake time (no re-alignment)
    }
  });
  th.join();
}

std::string row(const char* name, const Totals& t) {
  const DurationSummary s = summarize(t.latency);
  char buf[256];
  std::snprintf(buf, sizeof buf, "  %-34s %7llu %9s %9s %9s %9s %9s %6llu", name,
                static_cast<unsigned long long>(s.count), format_duration(s.p50).c_str(),
                format_duration(s.p99).c_str(), format_duration(s.p999).c_str(),
                format_duration(s.max).c_str(), format_duration(s.mean).c_str(),
                static_cast<unsigned long long>(t.overruns));
  return buf;
}

double ratio(nanoseconds a, nanoseconds b) {
  return b.count() > 0 ? static_cast<double>(a.count()) / static_cast<double>(b.count()) : 0.0;
}

std::string load_average() {
  std::ifstream in("/proc/loadavg");
  std::string a;
  in >> a;
  return a.empty() ? "?" : a;
}

void run_pass(const char* title, const RtOptions& o, nanoseconds per_loop, int rounds) {
  Totals ours, base;
  RtSetup got;
  const nanoseconds chunk = per_loop / rounds;
  for (int r = 0; r < rounds; ++r) {
    got = run_rt_loop(o, chunk, ours);
    run_sleep_until(o, chunk, base);
  }
  std::printf("%s\n  obtained: %s\n", title, got.describe().c_str());
  for (const auto& w : got.warnings) std::printf("  warning: %s\n", w.c_str());
  std::printf("  %-34s %7s %9s %9s %9s %9s %9s %6s\n", "loop", "cycles", "p50", "p99", "p99.9",
              "max", "mean", "late");
  std::printf("%s\n", row("RtLoop (clock_nanosleep ABSTIME)", ours).c_str());
  std::printf("%s\n", row("std::this_thread::sleep_until", base).c_str());
  const DurationSummary a = summarize(ours.latency), b = summarize(base.latency);
  std::printf("  ratio RtLoop / sleep_until: p50 %.2f, p99 %.2f, p99.9 %.2f, max %.2f\n",
              ratio(a.p50, b.p50), ratio(a.p99, b.p99), ratio(a.p999, b.p999), ratio(a.max, b.max));
  std::printf(
      "  (late: RtLoop overruns, re-aligned; sleep_until: woke after the next wake "
      "time)\n\n");
}

// The loop's own per-cycle cost: timer, both histograms and the seqlock publication, on a stepped
// clock (no sleeping), so only the bookkeeping is timed.
void bookkeeping_cost() {
  cdpr::controller::ManualLoopClock clock;
  clock.set_wake_latency(std::chrono::microseconds{40});
  cdpr::controller::PeriodicTimer timer(clock, std::chrono::milliseconds{4});
  cdpr::controller::CycleStatsBoard board;
  constexpr int kCycles = 200000;
  const auto t0 = Clock::now();
  for (int i = 0; i < kCycles; ++i) {
    timer.wait_next();
    clock.advance(nanoseconds{1000 + (i * 7919) % 50000});
    timer.end_cycle();
    board.publish(timer.stats());
  }
  const auto dt = Clock::now() - t0;
  std::printf("RtLoop bookkeeping per cycle (wait_next + end_cycle + publish, no sleep): %s\n",
              format_duration(dt / kCycles).c_str());
}

}  // namespace

int main(int argc, char** argv) {
  double seconds = 10;
  double period_ms = 4;
  int priority = 80;
  int rounds = 4;
  for (int i = 1; i + 1 < argc; i += 2) {
    if (!std::strcmp(argv[i], "--seconds"))
      seconds = std::atof(argv[i + 1]);
    else if (!std::strcmp(argv[i], "--period-ms"))
      period_ms = std::atof(argv[i + 1]);
    else if (!std::strcmp(argv[i], "--priority"))
      priority = std::atoi(argv[i + 1]);
    else if (!std::strcmp(argv[i], "--rounds"))
      rounds = std::atoi(argv[i + 1]);
    else {
      std::fprintf(stderr, "usage: %s [--seconds S] [--period-ms P] [--priority N] [--rounds R]\n",
                   argv[0]);
      return 2;
    }
  }
  if (seconds <= 0 || period_ms <= 0 || rounds < 1) {
    std::fprintf(stderr, "seconds, period and rounds must be positive\n");
    return 2;
  }
  const nanoseconds per_loop{static_cast<std::int64_t>(seconds * 1e9)};
  utsname u{};
  uname(&u);
  std::printf(
      "rt_loop_bench: wake-up latency at %.0f Hz (period %.3g ms), %.0f s per loop and "
      "pass in %d interleaved rounds\n",
      1000.0 / period_ms, period_ms, seconds, rounds);
  std::printf("machine: %ld CPUs, kernel %s %s, load average %s at start\n",
              sysconf(_SC_NPROCESSORS_ONLN), u.release, u.version, load_average().c_str());
  std::printf("percentiles from the log-linear histogram: at most %.1f %% above the true value\n\n",
              100 * DurationHistogram::kRelativeResolution);

  RtOptions normal;
  normal.period = nanoseconds{static_cast<std::int64_t>(period_ms * 1e6)};
  normal.priority = 0;
  normal.lock_memory = false;
  run_pass("pass 1: normal scheduler (SCHED_OTHER), memory not locked", normal, per_loop, rounds);

  RtOptions rt = normal;
  rt.priority = priority;
  rt.lock_memory = true;
  const RtSetup probe = [&] {
    RtSetup s;
    std::thread([&] { s = prepare_realtime(rt); }).join();
    return s;
  }();
  if (!probe.fifo) {
    std::printf(
        "pass 2: SCHED_FIFO %d is not available here, so the real-time figures cannot be "
        "measured on this machine:\n",
        priority);
    for (const auto& w : probe.warnings) std::printf("  %s\n", w.c_str());
    std::printf("\n");
  } else {
    char title[96];
    std::snprintf(title, sizeof title, "pass 2: SCHED_FIFO %d, memory locked (as cdprd)", priority);
    run_pass(title, rt, per_loop, rounds);
  }
  bookkeeping_cost();
  std::printf("load average %s at end\n", load_average().c_str());
  return 0;
}
