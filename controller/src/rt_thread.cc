#include "cdpr/controller/rt_thread.hpp"

#include <alloca.h>
#include <malloc.h>
#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/sysinfo.h>
#include <unistd.h>

#include <cassert>
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <fstream>
#include <string>
#include <system_error>

namespace cdpr::controller {

using std::chrono::nanoseconds;

namespace {

constexpr int kCapIpcLock = 14;  // linux/capability.h

// "EPERM (Operation not permitted)"
std::string errno_text(int err) {
  const char* name = strerrorname_np(err);
  return std::string(name != nullptr ? name : "errno " + std::to_string(err)) + " (" +
         std::strerror(err) + ")";
}

std::string bytes_text(std::size_t n) {
  char buf[32];
  if (n >= (std::size_t{1} << 20) && n % (std::size_t{1} << 20) == 0) {
    std::snprintf(buf, sizeof buf, "%zu MiB", n >> 20);
  } else if (n >= 1024 && n % 1024 == 0) {
    std::snprintf(buf, sizeof buf, "%zu KiB", n >> 10);
  } else {
    std::snprintf(buf, sizeof buf, "%zu bytes", n);
  }
  return buf;
}

std::string rlimit_text(rlim_t v) {
  return v == RLIM_INFINITY ? std::string("unlimited") : std::to_string(v);
}

// The effective capability set from /proc/self/status (CapEff, hexadecimal).
bool has_effective_capability(int cap) {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("CapEff:", 0) == 0) {
      const unsigned long long mask = std::strtoull(line.c_str() + 7, nullptr, 16);
      return (mask >> cap) & 1u;
    }
  }
  return false;
}

bool inside_user_mode_linux() {
  std::ifstream in("/proc/cpuinfo");
  std::string line;
  while (std::getline(in, line)) {
    if (line.find("User Mode Linux") != std::string::npos) return true;
  }
  return false;
}

void set_scheduler(const RtOptions& o, RtSetup& r) {
  if (o.priority == 0) return;  // the normal scheduler was asked for
  const int lo = sched_get_priority_min(SCHED_FIFO), hi = sched_get_priority_max(SCHED_FIFO);
  if (o.priority < lo || o.priority > hi) {
    r.warnings.push_back("SCHED_FIFO priority " + std::to_string(o.priority) + " is outside " +
                         std::to_string(lo) + ".." + std::to_string(hi) +
                         "; the RT loop runs under the normal scheduler. Fix: set the priority "
                         "in that range (80 is the default).");
    return;
  }
  sched_param p{};
  p.sched_priority = o.priority;
  const int err = pthread_setschedparam(pthread_self(), SCHED_FIFO, &p);
  if (err != 0) {
    rlimit rt{};
    getrlimit(RLIMIT_RTPRIO, &rt);
    std::string w =
        "SCHED_FIFO priority " + std::to_string(o.priority) + " refused: " + errno_text(err) + ". ";
    if (err == EPERM) {
      w += "The process may not use real-time priorities (it has no CAP_SYS_NICE and "
           "RLIMIT_RTPRIO is " +
           rlimit_text(rt.rlim_cur) +
           "; a cgroup without real-time CPU time refuses it too). The RT loop runs under the "
           "normal scheduler, so other load can delay its wake-ups. Fix: run cdprd from "
           "cdprd.service (LimitRTPRIO=95), or allow the user 'rtprio " +
           std::to_string(o.priority) + "' in /etc/security/limits.d/.";
    } else {
      w += "The RT loop runs under the normal scheduler.";
    }
    r.warnings.push_back(std::move(w));
    return;
  }
  int policy = 0;
  sched_param got{};
  if (pthread_getschedparam(pthread_self(), &policy, &got) == 0 && policy == SCHED_FIFO) {
    r.fifo = true;
    r.priority = got.sched_priority;
  }
}

void set_affinity(const RtOptions& o, RtSetup& r) {
  if (o.cpu < 0) return;
  const int configured = get_nprocs_conf();
  cpu_set_t allowed;
  CPU_ZERO(&allowed);
  std::string allowed_list;
  if (sched_getaffinity(0, sizeof allowed, &allowed) == 0) {
    for (int c = 0; c < CPU_SETSIZE; ++c) {
      if (CPU_ISSET(c, &allowed))
        allowed_list += (allowed_list.empty() ? "" : ",") + std::to_string(c);
    }
  }
  if (o.cpu >= CPU_SETSIZE || o.cpu >= configured) {
    r.warnings.push_back("CPU " + std::to_string(o.cpu) + " does not exist (this machine has " +
                         std::to_string(configured) +
                         " CPUs); the RT thread is not pinned. Fix: choose one of the CPUs " +
                         allowed_list + ", or -1 for no pinning.");
    return;
  }
  cpu_set_t set;
  CPU_ZERO(&set);
  CPU_SET(static_cast<std::size_t>(o.cpu), &set);
  const int err = pthread_setaffinity_np(pthread_self(), sizeof set, &set);
  if (err != 0) {
    r.warnings.push_back(
        "pinning the RT thread to CPU " + std::to_string(o.cpu) + " refused: " + errno_text(err) +
        ": the CPU is offline or outside the CPUs this process may use (" + allowed_list +
        "). The thread is not pinned, so it can migrate between CPUs. Fix: "
        "choose one of those CPUs (or -1), or widen the service's "
        "CPUAffinity=/AllowedCPUs=.");
    return;
  }
  r.cpu = o.cpu;
}

void lock_memory(RtSetup& r) {
  rlimit ml{};
  getrlimit(RLIMIT_MEMLOCK, &ml);
  const bool unlimited = ml.rlim_cur == RLIM_INFINITY;
  if (!unlimited && !has_effective_capability(kCapIpcLock)) {
    r.warnings.push_back(
        "memory not locked: RLIMIT_MEMLOCK is " + bytes_text(ml.rlim_cur) +
        " and the process has no CAP_IPC_LOCK. Locking all memory (now and future) under that "
        "limit would make every allocation fail once it is reached, so cdprd does not lock; "
        "page faults and swapping can delay the RT loop. Fix: LimitMEMLOCK=infinity in "
        "cdprd.service (as shipped), or 'memlock unlimited' for the user in "
        "/etc/security/limits.d/.");
    return;
  }
  if (mlockall(MCL_CURRENT | MCL_FUTURE) != 0) {
    const int err = errno;
    std::string w = "mlockall(MCL_CURRENT | MCL_FUTURE) failed: " + errno_text(err) + ". ";
    if (err == ENOMEM) {
      w += "More memory is mapped than may be locked (RLIMIT_MEMLOCK " + rlimit_text(ml.rlim_cur) +
           ") or the machine is short of memory. ";
    } else if (err == EPERM) {
      w += "The process may not lock memory. ";
    }
    w += "Memory is not locked, so page faults and swapping can delay the RT loop. Fix: "
         "LimitMEMLOCK=infinity in cdprd.service (as shipped).";
    r.warnings.push_back(std::move(w));
    return;
  }
  r.memory_locked = true;
}

void prefault_heap(std::size_t bytes, std::size_t page, RtSetup& r) {
  if (bytes == 0) return;
  // Keep what is freed (no trimming) and serve large blocks from the heap rather than from
  // mmap (which would return them to the system on free), so the touched pages stay.
  const bool trim = mallopt(M_TRIM_THRESHOLD, -1) == 1;
  const bool mmap_off = mallopt(M_MMAP_MAX, 0) == 1;
  if (!trim || !mmap_off) {
    r.warnings.push_back(
        "mallopt(M_TRIM_THRESHOLD / M_MMAP_MAX) refused: the pre-faulted heap may be returned "
        "to the system, and later allocations may fault pages in.");
  }
  auto* p = static_cast<volatile char*>(std::malloc(bytes));
  if (p == nullptr) {
    r.warnings.push_back("pre-faulting " + bytes_text(bytes) +
                         " of heap failed: malloc returned no memory. The heap is not "
                         "pre-faulted. Fix: a smaller prefault_heap_bytes, or more memory.");
    return;
  }
  for (std::size_t i = 0; i < bytes; i += page) p[i] = 1;
  p[bytes - 1] = 1;
  std::free(const_cast<char*>(p));
  r.heap_prefaulted = bytes;
}

[[gnu::noinline]] void touch_stack(std::size_t bytes, std::size_t page) {
  auto* p = static_cast<volatile char*>(alloca(bytes));
  for (std::size_t i = 0; i < bytes; i += page) p[i] = 0;
  p[bytes - 1] = 0;
}

void prefault_stack(std::size_t bytes, std::size_t page, RtSetup& r) {
  if (bytes == 0) return;
  // What is left below this frame, with a margin for the frames of the touch itself and the
  // guard page.
  constexpr std::size_t kMargin = 64 * 1024;
  pthread_attr_t attr;
  std::size_t available = 0;
  if (pthread_getattr_np(pthread_self(), &attr) == 0) {
    void* base = nullptr;
    std::size_t size = 0;
    if (pthread_attr_getstack(&attr, &base, &size) == 0) {
      const char here = 0;
      const auto used_top = reinterpret_cast<std::uintptr_t>(&here);
      const auto lowest = reinterpret_cast<std::uintptr_t>(base);
      if (used_top > lowest + kMargin) available = used_top - lowest - kMargin;
    }
    pthread_attr_destroy(&attr);
  }
  std::size_t n = bytes;
  if (n > available) {
    r.warnings.push_back("the RT thread's stack has " + bytes_text(available) +
                         " free, less than the " + bytes_text(bytes) +
                         " to pre-fault; pre-faulted " + bytes_text(available) +
                         ". Fix: a smaller prefault_stack_bytes, or a larger stack "
                         "(LimitSTACK= / ulimit -s).");
    n = available;
  }
  if (n == 0) return;
  touch_stack(n, page);
  r.stack_prefaulted = n;
}

}  // namespace

std::string RtSetup::describe() const {
  std::string s = fifo ? "SCHED_FIFO " + std::to_string(priority) : std::string("normal scheduler");
  s += cpu >= 0 ? ", CPU " + std::to_string(cpu) : std::string(", not pinned");
  s += memory_locked ? ", memory locked" : ", memory not locked";
  s += ", " + bytes_text(stack_prefaulted) + " stack and " + bytes_text(heap_prefaulted) +
       " heap pre-faulted";
  if (user_mode_linux) s += ", inside user-mode-linux";
  return s;
}

RtSetup prepare_realtime(const RtOptions& options) {
  RtSetup r;
  const long page_l = sysconf(_SC_PAGESIZE);
  const std::size_t page = page_l > 0 ? static_cast<std::size_t>(page_l) : 4096;
  r.user_mode_linux = inside_user_mode_linux();
  if (r.user_mode_linux) {
    r.warnings.push_back(
        "running inside user-mode-linux: its scheduler and memory lock do not reach the host, "
        "so wake-ups can be late by milliseconds. Use a period of 20 ms or more there; this is "
        "a test set-up, not a robot controller.");
  }
  set_scheduler(options, r);
  set_affinity(options, r);
  // Timer expiry may be deferred by the thread's timer slack (50 us by default; the kernel
  // ignores it for SCHED_FIFO threads). 1 ns is the smallest allowed value.
  prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL);
  r.timer_slack_ns = prctl(PR_GET_TIMERSLACK, 0UL, 0UL, 0UL, 0UL);
  if (options.lock_memory) lock_memory(r);
  prefault_heap(options.prefault_heap_bytes, page, r);
  prefault_stack(options.prefault_stack_bytes, page, r);
  return r;
}

Status validate(const RtOptions& o) {
  if (o.period <= nanoseconds{0} || o.period > std::chrono::seconds{10}) {
    return Status::error(ErrorCode::kOutOfRange, "period %lld ns is outside (0, 10 s]",
                         static_cast<long long>(o.period.count()));
  }
  const int hi = sched_get_priority_max(SCHED_FIFO);
  if (o.priority < 0 || o.priority > hi) {
    return Status::error(ErrorCode::kOutOfRange,
                         "priority %d is outside 0..%d (0: normal scheduler)", o.priority, hi);
  }
  if (o.cpu < -1 || o.cpu >= CPU_SETSIZE) {
    return Status::error(ErrorCode::kOutOfRange, "cpu %d is outside -1..%d (-1: not pinned)", o.cpu,
                         CPU_SETSIZE - 1);
  }
  constexpr std::size_t kMaxStack = 64u << 20, kMaxHeap = std::size_t{16} << 30;
  if (o.prefault_stack_bytes > kMaxStack) {
    return Status::error(ErrorCode::kOutOfRange, "prefault_stack_bytes %zu is above %zu",
                         o.prefault_stack_bytes, kMaxStack);
  }
  if (o.prefault_heap_bytes > kMaxHeap) {
    return Status::error(ErrorCode::kOutOfRange, "prefault_heap_bytes %zu is above %zu",
                         o.prefault_heap_bytes, kMaxHeap);
  }
  return Status::success();
}

// ---------------------------------------------------------------------------------------------
// Clocks

MonoTime MonotonicLoopClock::now() noexcept {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return MonoTime{static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec};
}

void MonotonicLoopClock::sleep_until(MonoTime deadline) noexcept {
  timespec ts{};
  ts.tv_sec = static_cast<time_t>(deadline.count() / 1'000'000'000);
  ts.tv_nsec = static_cast<long>(deadline.count() % 1'000'000'000);
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
  }
}

MonotonicLoopClock& monotonic_loop_clock() {
  static MonotonicLoopClock clock;
  return clock;
}

void ManualLoopClock::sleep_until(MonoTime deadline) noexcept {
  const std::int64_t latency = latency_.load(std::memory_order_acquire);
  std::int64_t cur = now_.load(std::memory_order_acquire);
  std::int64_t next = 0;
  do {
    next = (cur > deadline.count() ? cur : deadline.count()) + latency;
  } while (!now_.compare_exchange_weak(cur, next, std::memory_order_acq_rel));
  sleeps_.fetch_add(1, std::memory_order_acq_rel);
}

// ---------------------------------------------------------------------------------------------
// PeriodicTimer

PeriodicTimer::PeriodicTimer(LoopClock& clock, nanoseconds period) noexcept
    : clock_(clock), period_(period) {
  assert(period > nanoseconds{0});
}

void PeriodicTimer::start() noexcept {
  start(clock_.now() + period_);
}

void PeriodicTimer::start(MonoTime first_wake) noexcept {
  next_ = first_wake;
  started_ = true;
  in_cycle_ = false;
  cycles_ = 0;
  tick_ = 0;
  pending_skipped_ = 0;
}

Wake PeriodicTimer::wait_next() noexcept {
  if (in_cycle_) end_cycle();
  if (!started_) start();
  clock_.sleep_until(next_);
  const MonoTime t = clock_.now();
  current_ = Wake{next_, t, t - next_, cycles_, tick_, pending_skipped_};
  pending_skipped_ = 0;
  in_cycle_ = true;
  return current_;
}

CycleEnd PeriodicTimer::end_cycle() noexcept {
  if (!in_cycle_) return {};
  in_cycle_ = false;
  const MonoTime t = clock_.now();
  CycleEnd e;
  e.compute = t - current_.now;
  const MonoTime following = current_.nominal + period_;
  if (t > following) {
    // The first grid point strictly after the end of the compute.
    e.skipped = static_cast<std::uint64_t>((t - following) / period_) + 1;
    e.overrun = true;
  }
  next_ = following + static_cast<std::int64_t>(e.skipped) * period_;
  e.next_wake = next_;
  tick_ += 1 + e.skipped;
  ++cycles_;
  pending_skipped_ = e.skipped;
  stats_.record_cycle(current_.latency, e.compute, e.overrun, e.skipped);
  return e;
}

// ---------------------------------------------------------------------------------------------
// RtLoop

RtLoop::RtLoop(RtOptions options, CycleHandler& handler, LoopClock& clock)
    : options_(options), handler_(handler), clock_(clock) {}

RtLoop::~RtLoop() {
  stop();
}

Status RtLoop::start() {
  if (Status st = validate(options_); !st) return st.prepend("RT loop options: ");
  if (thread_.joinable()) {
    return Status(ErrorCode::kFailedPrecondition, "the RT loop is already running");
  }
  stop_.store(false, std::memory_order_release);
  set_up_.store(false, std::memory_order_release);
  running_.store(true, std::memory_order_release);
  try {
    thread_ = std::thread([this] { run(); });
  } catch (const std::system_error& e) {
    running_.store(false, std::memory_order_release);
    return Status::error(ErrorCode::kUnavailable, "cannot create the RT thread: %s", e.what());
  }
  set_up_.wait(false, std::memory_order_acquire);
  return Status::success();
}

void RtLoop::stop() {
  request_stop();
  if (thread_.joinable()) thread_.join();
}

void RtLoop::run() noexcept {
  pthread_setname_np(pthread_self(), "cdpr-rt");
  setup_ = prepare_realtime(options_);
  // Built (and its histograms written) before the first cycle, so their pages are present.
  PeriodicTimer timer(clock_, options_.period);
  board_.publish(timer.stats());
  set_up_.store(true, std::memory_order_release);
  set_up_.notify_all();
  // cycles() keeps counting across a stop() and start(): the watchdog sees progress only.
  const std::uint64_t base = cycles_.load(std::memory_order_relaxed);
  timer.start();
  while (!stop_.load(std::memory_order_acquire)) {
    const Wake w = timer.wait_next();
    if (stop_.load(std::memory_order_acquire)) break;
    handler_.cycle(w);
    timer.end_cycle();
    board_.publish(timer.stats());
    cycles_.store(base + timer.stats().cycles(), std::memory_order_release);
  }
  running_.store(false, std::memory_order_release);
}

}  // namespace cdpr::controller
