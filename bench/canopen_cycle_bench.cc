// Per-cycle CPU cost of the CANopen master for the MINI network (8 CiA 402 drives in CSP and one
// force node, config/canopen-mini.yaml) on the in-process virtual bus.
//
// The network is booted and enabled against simulated slaves; then each benchmark iteration
// injects the 10 TPDOs the nodes send after a SYNC (from a peer endpoint) and runs one
// Master::cycle(): drain and decode 10 TPDOs, run 8 drive supervisors, encode and send 8 RPDOs
// plus SYNC. BM_InjectOnly measures the injection alone, so the master's own cost is the
// difference. Allocations per cycle are counted with the global operator new counter.
#include <benchmark/benchmark.h>

#include <cstdio>

#include "alloc_counter.hpp"
#include "cdpr/canopen/master.hpp"
#include "testing/sim_network.hpp"

namespace {

using namespace cdpr;
using namespace cdpr::canopen;
using namespace std::chrono_literals;

struct Rig {
  testing::SimNetwork net;
  std::unique_ptr<Master> master;
  std::unique_ptr<can::VirtualCanEndpoint> peer;
  std::array<can::Frame, 10> tpdos{};

  Rig() {
    auto c = load_config(CDPR_SOURCE_DIR "/config/canopen-mini.yaml");
    if (!c.ok()) std::abort();
    for (NodeId id = 1; id <= 8; ++id) net.add<slave::Drive402>(id, 1000 * id);
    auto& force = net.add<slave::SlaveNode>(9);
    for (std::uint8_t ch = 1; ch <= 8; ++ch) force.od().add({0x6401, ch}, DataType::kI16, 2 * ch);
    net.power_on();
    MasterHooks hooks{[this] { return net.now(); }, [this] { net.idle(); }, 0ns};
    auto m = Master::create(net.master_bus(), *c, hooks);
    if (!m.ok()) std::abort();
    master = std::move(*m);
    if (!master->boot().ok() || !master->enable_all(2s).ok()) {
      std::fprintf(stderr, "boot/enable failed\n");
      std::abort();
    }
    peer = net.bus().endpoint("peer");
    for (NodeId id = 1; id <= 8; ++id) {
      can::Frame& f = tpdos[id - 1];
      f = make_frame(cob::tpdo(1, id), 6);
      put_u16(&f.data[0], 0x0237);  // OPERATION_ENABLED
      put_u32(&f.data[2], 1000u * id);
    }
    tpdos[8] = make_frame(cob::tpdo(1, 9), 8);
    tpdos[9] = make_frame(cob::tpdo(2, 9), 8);
  }
  void inject() {
    for (const auto& f : tpdos) (void)peer->send(f);
  }
};

Rig& rig() {
  static Rig r;
  return r;
}

void BM_MasterCycle(benchmark::State& state) {
  Rig& r = rig();
  std::uint64_t allocs = 0, cycles = 0;
  Timestamp now = r.net.now();
  for (auto _ : state) {
    r.inject();
    const std::uint64_t before = cdpr::test::thread_allocations();
    now += 4ms;
    r.master->cycle(now);
    allocs += cdpr::test::thread_allocations() - before;
    ++cycles;
  }
  state.counters["allocs_per_cycle"] = static_cast<double>(allocs) / static_cast<double>(cycles);
  state.counters["drives_enabled"] = 0;
  for (const Drive& d : r.master->drives()) state.counters["drives_enabled"] += d.enabled() ? 1 : 0;
  state.counters["tpdos_per_cycle"] = static_cast<double>(r.master->stats().tpdos_received) /
                                      static_cast<double>(r.master->stats().cycles);
}
BENCHMARK(BM_MasterCycle);

void BM_InjectOnly(benchmark::State& state) {
  Rig& r = rig();
  can::Frame f;
  for (auto _ : state) {
    r.inject();
    while (r.net.master_bus().receive(f, 0ns).ok()) benchmark::DoNotOptimize(f);
  }
}
BENCHMARK(BM_InjectOnly);

void BM_Cia402NextControlword(benchmark::State& state) {
  std::uint16_t sw = 0x0040, cw = 0;
  for (auto _ : state) {
    cw = cia402::next_controlword(sw, cia402::Target::kOperationEnabled, false, cw);
    benchmark::DoNotOptimize(cw);
    sw = static_cast<std::uint16_t>(sw == 0x0040 ? 0x0021 : (sw == 0x0021 ? 0x0023 : 0x0040));
  }
}
BENCHMARK(BM_Cia402NextControlword);

}  // namespace

BENCHMARK_MAIN();
