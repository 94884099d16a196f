#include "cdpr/sim/can_robot.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>

#include "cdpr/canopen/types.hpp"

namespace cdpr::sim {

namespace co = cdpr::canopen;
namespace cos = cdpr::canopen::slave;
using std::chrono::nanoseconds;

// One node's endpoint: frames the robot took from the shared bus are queued here; what the node
// sends goes to the shared bus (or nowhere while the bus is off).
class CanRobot::Port final : public can::CanBus {
 public:
  Port(CanRobot& robot, std::string name) : robot_(robot), name_(std::move(name)) {}

  Status send(const can::Frame& f) override {
    if (robot_.bus_off_) {
      ++robot_.stats_.frames_dropped_bus_off;
      return Status::success();
    }
    ++stats_.frames_sent;
    return robot_.bus_.send(f);
  }
  Status receive(can::Frame& f, nanoseconds) override {
    if (rx_.empty()) return Status::error(ErrorCode::kTimeout, "%s: no frame", name_.c_str());
    f = rx_.front();
    rx_.pop_front();
    ++stats_.frames_received;
    return Status::success();
  }
  const std::string& name() const override { return name_; }
  can::BusStats stats() const override { return stats_; }
  void push(const can::Frame& f) { rx_.push_back(f); }

 private:
  CanRobot& robot_;
  std::string name_;
  std::deque<can::Frame> rx_;
  can::BusStats stats_;
};

namespace {

bool is_sync(const can::Frame& f) {
  return !f.error && !f.extended && !f.rtr && f.id == co::cob::kSync;
}

std::int64_t saturate(double v, co::DataType t) {
  double lo = 0.0, hi = 0.0;
  switch (t) {
    case co::DataType::kI8:
      lo = -128.0, hi = 127.0;
      break;
    case co::DataType::kU8:
      lo = 0.0, hi = 255.0;
      break;
    case co::DataType::kI16:
      lo = -32768.0, hi = 32767.0;
      break;
    case co::DataType::kU16:
      lo = 0.0, hi = 65535.0;
      break;
    case co::DataType::kI32:
      lo = -2147483648.0, hi = 2147483647.0;
      break;
    case co::DataType::kU32:
      lo = 0.0, hi = 4294967295.0;
      break;
  }
  return static_cast<std::int64_t>(std::clamp(std::round(v), lo, hi));
}

}  // namespace

CanRobot::CanRobot(can::CanBus& bus, Physics& physics, CanRobotOptions options)
    : bus_(bus), physics_(physics), options_(std::move(options)) {}

CanRobot::~CanRobot() = default;

Result<std::unique_ptr<CanRobot>> CanRobot::create(can::CanBus& bus,
                                                   const co::MasterConfig& network,
                                                   Physics& physics, CanRobotOptions options) {
  const int m = physics.truth().num_cables();
  if (!options.initial_counts.empty() && static_cast<int>(options.initial_counts.size()) != m) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "CAN robot: %zu initial counts for a robot with %d cables",
                         options.initial_counts.size(), m);
  }
  std::unique_ptr<CanRobot> r(new CanRobot(bus, physics, std::move(options)));
  for (const co::NodeConfig& n : network.nodes) {
    auto port = std::make_unique<Port>(*r, bus.name() + "/node" + std::to_string(n.id));
    std::unique_ptr<cos::SlaveNode> node;
    std::uint32_t product = 0;
    if (n.kind == co::NodeKind::kCia402Drive) {
      const auto cable = r->drives_.size();
      if (static_cast<int>(cable) >= m) {
        return Status::error(ErrorCode::kInvalidArgument,
                             "CAN robot: node %u (%s): more cia402 drives than the robot's %d "
                             "cables",
                             unsigned{n.id}, n.name.c_str(), m);
      }
      const std::int32_t start =
          r->options_.initial_counts.empty() ? 0 : r->options_.initial_counts[cable];
      auto d = std::make_unique<cos::Drive402>(*port, n.id, start);
      r->drives_.push_back(d.get());
      node = std::move(d);
      product = r->options_.drive_product_code;
    } else {
      node = std::make_unique<cos::SlaveNode>(*port, n.id);
      if (n.kind == co::NodeKind::kForceSensor) {
        node->od().set_default({0x1000, 0}, 0x00000194);  // CiA 404 measuring device
        product = r->options_.force_product_code;
        r->force_nodes_.push_back(node.get());
      } else {
        node->od().set_default({0x1000, 0}, 0);
      }
    }
    // A node whose configuration names an EDS gets exactly the dictionary it describes (default
    // PDO mappings included), so the simulator and the master's checks share one description.
    const bool from_eds = n.eds_data != nullptr;
    if (from_eds) {
      const Status st = node->load_eds(*n.eds_data);
      if (!st.ok()) {
        return Status::error(st.code(), "CAN robot: node %u (%s): %.*s", unsigned{n.id},
                             n.name.c_str(), static_cast<int>(st.message().size()),
                             st.message().data());
      }
    }
    cos::ObjectDictionary& od = node->od();
    od.add({0x1018, 1}, co::DataType::kU32, r->options_.vendor_id, cos::Access::kRo);
    od.add({0x1018, 2}, co::DataType::kU32, product, cos::Access::kRo);
    od.add({0x1018, 3}, co::DataType::kU32, r->options_.revision, cos::Access::kRo);
    od.add({0x1018, 4}, co::DataType::kU32, r->options_.serial_base + n.id, cos::Access::kRo);
    od.add_string({0x1008, 0}, "cdpr-sim " + n.name, cos::Access::kConst);
    if (n.heartbeat_period.count() > 0) {
      od.set_default(
          {0x1017, 0},
          std::chrono::duration_cast<std::chrono::milliseconds>(n.heartbeat_period).count());
    }
    // Without an EDS, every object the configuration maps or writes exists (new ones start at
    // 0); with one, the master's load checked that the EDS has them.
    for (const co::PdoConfig& p : n.rpdos) {
      for (const co::PdoEntry& e : p.entries) {
        if (!from_eds && od.find(e.object) == nullptr) {
          od.add(e.object, e.type, 0, cos::Access::kRw);
        }
      }
    }
    for (const co::PdoConfig& p : n.tpdos) {
      for (const co::PdoEntry& e : p.entries) {
        if (!from_eds && od.find(e.object) == nullptr) {
          od.add(e.object, e.type, 0, cos::Access::kRo);
        }
        if (n.kind == co::NodeKind::kForceSensor) {
          r->force_channels_.push_back({node.get(), e.object, e.type});
        }
      }
    }
    for (const co::SdoWrite& w : n.sdo_writes) {
      if (!from_eds && od.find(w.object) == nullptr) od.add(w.object, w.type, 0, cos::Access::kRw);
    }
    r->ports_.push_back(std::move(port));
    r->nodes_.push_back(std::move(node));
  }
  if (static_cast<int>(r->drives_.size()) != m) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "CAN robot: the network has %zu cia402 drives, the robot %d cables",
                         r->drives_.size(), m);
  }
  if (!r->force_channels_.empty() && static_cast<int>(r->force_channels_.size()) != m) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "CAN robot: the force-sensor nodes map %zu channels, the robot has %d "
                         "cables (one channel per cable, or none)",
                         r->force_channels_.size(), m);
  }
  const Scenario& sc = physics.scenario();
  r->overload_emcy_.assign(static_cast<std::size_t>(m), 0);
  r->overload_tripped_.assign(static_cast<std::size_t>(m), false);
  for (const Fault& f : sc.faults) {
    const bool needs_cable = f.kind == FaultKind::kDriveFault ||
                             f.kind == FaultKind::kDriveSilent || f.kind == FaultKind::kSdoAbort ||
                             f.kind == FaultKind::kCableOverload;
    if (needs_cable && (f.cable < 0 || f.cable >= m)) {
      return Status::error(ErrorCode::kInvalidArgument, "%s:%d: faults: %s: cable %d is not 1..%d",
                           sc.file.c_str(), f.line, std::string(to_string(f.kind)).c_str(),
                           f.cable + 1, m);
    }
    if (f.kind == FaultKind::kCableOverload && r->overload_emcy_[f.cable] == 0) {
      r->overload_emcy_[f.cable] = f.emcy_code != 0 ? f.emcy_code : 0x2310;
    }
  }
  r->fault_applied_.assign(sc.faults.size(), false);
  r->fault_active_.assign(sc.faults.size(), false);
  r->force_fault_.assign(static_cast<std::size_t>(m), ForceChannelFault::kNone);
  r->force_fault_raw_.assign(static_cast<std::size_t>(m), 0.0);
  r->slip_counts_.assign(static_cast<std::size_t>(m), 0.0);
  return r;
}

double CanRobot::scenario_time(Timestamp now) const {
  if (!powered_) return 0.0;
  return std::max(0.0, std::chrono::duration<double>(now - t0_).count());
}

cos::SlaveNode& CanRobot::node(co::NodeId id) {
  for (auto& n : nodes_) {
    if (n->id() == id) return *n;
  }
  std::fprintf(stderr, "CanRobot::node(%u): no such node\n", unsigned{id});
  std::abort();
}

void CanRobot::say(double t, const std::string& what) {
  if (options_.report) options_.report(t, what);
}

void CanRobot::power_on(Timestamp now) {
  t0_ = now;
  powered_ = true;
  last_t_ = 0.0;
  for (auto& n : nodes_) n->power_on(now);
  step_physics(0.0);  // after the power-on: a cable overloaded at once faults its drive
}

bool CanRobot::wait(nanoseconds timeout) {
  can::Frame f;
  if (!bus_.receive(f, timeout).ok()) return false;
  waiting_.push_back(f);
  return true;
}

void CanRobot::apply_faults(double t) {
  const auto& faults = physics_.scenario().faults;
  char buf[160];
  for (std::size_t k = 0; k < faults.size(); ++k) {
    const Fault& f = faults[k];
    if (!f.is_can()) continue;
    if (f.kind == FaultKind::kDriveFault) {
      if (fault_applied_[k] || t < f.at_s) continue;
      fault_applied_[k] = true;
      const std::uint16_t code = f.emcy_code != 0 ? f.emcy_code : 0x2310;
      drive(f.cable).inject_fault(code);
      std::snprintf(buf, sizeof buf, "drive fault: node %u (cable %d) EMCY 0x%04X",
                    unsigned{drive(f.cable).id()}, f.cable + 1, code);
      say(t, buf);
      continue;
    }
    const bool active = f.active_at(t);
    if (active == fault_active_[k]) continue;
    fault_active_[k] = active;
    switch (f.kind) {
      case FaultKind::kDriveSilent:
        drive(f.cable).faults().silent = active;
        std::snprintf(buf, sizeof buf, "node %u (cable %d) %s", unsigned{drive(f.cable).id()},
                      f.cable + 1, active ? "falls silent" : "speaks again");
        break;
      case FaultKind::kSdoAbort: {
        const auto key = co::ObjectAddress{f.object, f.subindex}.key();
        auto& aborts = drive(f.cable).faults().abort_on;
        if (active) {
          aborts[key] = f.abort_code;
        } else {
          aborts.erase(key);
        }
        std::snprintf(buf, sizeof buf, "node %u (cable %d): SDO access to 0x%04X:%02X %s 0x%08X",
                      unsigned{drive(f.cable).id()}, f.cable + 1, unsigned{f.object},
                      unsigned{f.subindex}, active ? "aborted with" : "no longer aborted with",
                      f.abort_code);
        break;
      }
      case FaultKind::kBusOff:
        set_bus_off(active);
        std::snprintf(buf, sizeof buf, "bus %s", active ? "off" : "restarted");
        break;
      default:
        continue;
    }
    say(t, buf);
  }
}

void CanRobot::set_bus_off(bool on) {
  if (on == bus_off_) return;
  can::Frame e;
  e.error = true;
  e.dlc = 8;
  if (on) {
    e.error_class = can::error_class::kBusOff;
    (void)bus_.send(e);
    bus_off_ = true;
    waiting_.clear();
  } else {
    bus_off_ = false;
    e.error_class = can::error_class::kRestarted;
    (void)bus_.send(e);
  }
}

void CanRobot::set_force_fault(int cable, ForceChannelFault fault, double raw) {
  if (cable < 0 || cable >= num_cables()) return;
  force_fault_[static_cast<std::size_t>(cable)] = fault;
  force_fault_raw_[static_cast<std::size_t>(cable)] = raw;
}

void CanRobot::set_cable_slip(int cable, double counts) {
  if (cable < 0 || cable >= num_cables()) return;
  slip_counts_[static_cast<std::size_t>(cable)] = counts;
}

void CanRobot::deliver(const can::Frame& f) {
  for (auto& p : ports_) p->push(f);
}

void CanRobot::step_physics(double t) {
  const int m = num_cables();
  Eigen::VectorXd counts(m);
  for (int i = 0; i < m; ++i) {
    counts(i) = static_cast<double>(drive(i).shaft()) + slip_counts_[static_cast<std::size_t>(i)];
  }
  const Status st = physics_.step(counts, t);
  if (!st.ok()) {
    ++stats_.physics_failures;
    if (!physics_failing_) say(t, "physics: " + st.to_string() + " (previous state kept)");
    physics_failing_ = true;
    return;
  }
  if (physics_failing_) say(t, "physics: equilibrium found again");
  physics_failing_ = false;
  ++stats_.physics_steps;
  const PhysicsState& s = physics_.state();
  for (std::size_t k = 0; k < force_channels_.size(); ++k) {
    if (force_fault_[k] == ForceChannelFault::kStuck) continue;
    const double raw = force_fault_[k] == ForceChannelFault::kRaw
                           ? force_fault_raw_[k]
                           : s.force_raw(static_cast<int>(k));
    if (!std::isfinite(raw)) continue;
    const ForceChannel& ch = force_channels_[k];
    ch.node->od().set(ch.object, saturate(raw, ch.type));
  }
  for (int i = 0; i < m; ++i) {
    const auto u = static_cast<std::size_t>(i);
    if (u >= s.overloaded.size() || !s.overloaded[u] || overload_tripped_[u]) continue;
    overload_tripped_[u] = true;
    const std::uint16_t code = overload_emcy_[u] != 0 ? overload_emcy_[u] : 0x2310;
    drive(i).inject_fault(code);
    char buf[160];
    std::snprintf(buf, sizeof buf, "cable %d overloaded (%.1f N): node %u faults with EMCY 0x%04X",
                  i + 1, s.tensions(i), unsigned{drive(i).id()}, code);
    say(t, buf);
  }
}

void CanRobot::on_sync(Timestamp now) {
  ++stats_.syncs;
  // Drives first (they apply their RPDOs and move), then the physics, then the force nodes.
  for (auto* d : drives_) d->step(now);
  step_physics(last_t_);
  for (auto* n : force_nodes_) n->step(now);
}

void CanRobot::set_estop(bool open) {
  for (auto* d : drives_) d->set_digital_input(canopen::slave::Drive402::kSafetyInputBit, !open);
}

void CanRobot::step(Timestamp now) {
  if (!powered_) return;
  const double t = scenario_time(now);
  last_t_ = std::max(last_t_, t);
  apply_faults(last_t_);
  can::Frame f;
  while (bus_.receive(f, nanoseconds(0)).ok()) waiting_.push_back(f);
  while (!waiting_.empty()) {
    f = waiting_.front();
    waiting_.pop_front();
    if (bus_off_) {
      ++stats_.frames_dropped_bus_off;
      continue;
    }
    deliver(f);
    if (is_sync(f)) on_sync(now);
  }
  for (auto& n : nodes_) n->step(now);
}

}  // namespace cdpr::sim
