// Test fixture: a master endpoint and simulated slaves on one in-process virtual bus with a manual
// clock. Time advances only in idle(): 0.25 ms per call, after which every slave processes its
// frames. Deterministic and single-threaded.
#pragma once

#include <chrono>
#include <memory>
#include <vector>

#include "cdpr/can/virtual_bus.hpp"
#include "cdpr/canopen/slave/slave.hpp"

namespace cdpr::canopen::testing {

class SimNetwork {
 public:
  explicit SimNetwork(can::VirtualBusOptions options = {})
      : bus_(clock_, options), master_ep_(bus_.endpoint("master")) {}

  can::CanBus& master_bus() { return *master_ep_; }
  can::VirtualCanBus& bus() { return bus_; }
  cdpr::ManualClock& clock() { return clock_; }
  Timestamp now() const { return clock_.now(); }

  template <typename T, typename... Args>
  T& add(NodeId id, Args&&... args) {
    endpoints_.push_back(bus_.endpoint("node" + std::to_string(id)));
    auto node = std::make_unique<T>(*endpoints_.back(), id, std::forward<Args>(args)...);
    T& ref = *node;
    slaves_.push_back(std::move(node));
    return ref;
  }

  void power_on() {
    for (auto& s : slaves_) s->power_on(now());
  }
  void step_slaves() {
    for (auto& s : slaves_) s->step(now());
  }
  void idle() {
    clock_.advance(step_);
    step_slaves();
  }
  std::chrono::nanoseconds step() const { return step_; }

 private:
  cdpr::ManualClock clock_;
  can::VirtualCanBus bus_;
  std::unique_ptr<can::VirtualCanEndpoint> master_ep_;
  std::vector<std::unique_ptr<can::VirtualCanEndpoint>> endpoints_;
  std::vector<std::unique_ptr<slave::SlaveNode>> slaves_;
  std::chrono::nanoseconds step_{std::chrono::microseconds(250)};
};

}  // namespace cdpr::canopen::testing
