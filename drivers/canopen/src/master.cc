#include "cdpr/canopen/master.hpp"

#include <algorithm>
#include <cmath>
#include <string>

#include "cdpr/canopen/codes.hpp"
#include "cdpr/canopen/eds.hpp"
#include "cdpr/canopen/eds_check.hpp"

namespace cdpr::canopen {

Master::Master(can::CanBus& bus, MasterConfig config, MasterHooks hooks)
    : bus_(bus), config_(std::move(config)), hooks_(std::move(hooks)) {
  node_index_.fill(-1);
  sync_ = SyncProducer(config_.sync_period, config_.sync_counter_overflow);
  heartbeat_ = HeartbeatProducer(config_.heartbeat_cob_id(), config_.master_heartbeat_period);
  bus_sup_ = BusSupervisor(BusRecoveryPolicy{config_.bus_off_recovery});
}

Result<std::unique_ptr<Master>> Master::create(can::CanBus& bus, MasterConfig config,
                                               MasterHooks hooks) {
  CDPR_RETURN_IF_ERROR(validate(config));
  if (!hooks.now)
    return Status(ErrorCode::kInvalidArgument, "CANopen master: hooks.now is not set");
  std::unique_ptr<Master> m(new Master(bus, std::move(config), std::move(hooks)));
  const SdoTiming timing{m->config_.sdo_timeout, m->config_.sdo_retries, m->config_.sdo_quiet};
  std::size_t n_drives = 0;
  for (const auto& nc : m->config_.nodes) n_drives += nc.kind == NodeKind::kCia402Drive ? 1 : 0;
  m->drives_.reserve(n_drives);
  for (const auto& nc : m->config_.nodes) {
    auto rt = std::make_unique<NodeRt>();
    rt->config = nc;
    rt->sdo = std::make_unique<SdoClient>(bus, nc.id, timing);
    // What the node confirmed is what the master applied (kept for the DCF).
    rt->sdo->set_download_observer(
        [n = rt.get()](ObjectAddress a, std::span<const std::uint8_t> data) {
          if (data.empty() || data.size() > 8) return;
          std::uint64_t v = 0;
          for (std::size_t i = 0; i < data.size(); ++i) v |= std::uint64_t{data[i]} << (8 * i);
          n->applied[a.key()] = static_cast<std::int64_t>(v);
          n->applied_size[a.key()] = static_cast<std::uint8_t>(data.size());
        });
    for (const auto& p : nc.rpdos) {
      if (p.entries.empty()) continue;
      auto l = PdoLayout::compile(p, nc.id, rt->image);
      if (!l.ok()) return l.status();
      rt->rpdos.push_back(*l);
    }
    for (const auto& p : nc.tpdos) {
      if (p.entries.empty()) continue;
      auto l = PdoLayout::compile(p, nc.id, rt->image);
      if (!l.ok()) return l.status();
      TpdoRef& ref = m->tpdo_table_[l->cob_id() & 0x7FF];
      ref.node = static_cast<std::int16_t>(m->nodes_.size());
      ref.pdo = static_cast<std::int16_t>(rt->tpdos.size());
      rt->tpdos.push_back(*l);
    }
    if (nc.kind == NodeKind::kCia402Drive) {
      auto d = Drive::bind(nc, rt->image);
      if (!d.ok()) return d.status();
      rt->drive = static_cast<int>(m->drives_.size());
      m->drives_.push_back(*d);
    } else if (nc.kind == NodeKind::kForceSensor) {
      auto f = ForceSensor::bind(nc, rt->image);
      if (!f.ok()) return f.status();
      rt->force = static_cast<int>(m->forces_.size());
      m->forces_.push_back(std::move(*f));
    }
    m->node_index_[nc.id] = static_cast<int>(m->nodes_.size());
    m->nodes_.push_back(std::move(rt));
  }
  return m;
}

Drive* Master::drive(NodeId id) {
  NodeRt* n = node(id);
  return n && n->drive >= 0 ? &drives_[static_cast<std::size_t>(n->drive)] : nullptr;
}
ForceSensor* Master::force_sensor(NodeId id) {
  NodeRt* n = node(id);
  return n && n->force >= 0 ? &forces_[static_cast<std::size_t>(n->force)] : nullptr;
}
SdoClient* Master::sdo(NodeId id) {
  NodeRt* n = node(id);
  return n ? n->sdo.get() : nullptr;
}
ProcessImage* Master::image(NodeId id) {
  NodeRt* n = node(id);
  return n ? &n->image : nullptr;
}

void Master::send(const can::Frame& f, Timestamp now) {
  if (!bus_.send(f).ok()) {
    ++stats_.tx_failures;
    Event e;
    e.type = EventType::kTxFailed;
    e.value = f.id;
    e.time = now;
    events_.push(e);
  }
}

void Master::dispatch(const can::Frame& f, Timestamp now) {
  if (f.error) {
    bus_sup_.on_error_frame(f, now, events_);
    return;
  }
  if (f.extended || f.rtr || f.id > 0x7FF) {
    ++stats_.unknown_frames;
    return;
  }
  const std::uint32_t id = f.id;
  if (id > cob::kHeartbeat && id <= cob::kHeartbeat + kMaxNodeId) {
    const auto nid = static_cast<NodeId>(id - cob::kHeartbeat);
    const bool booted = f.dlc == 1 && f.data[0] == 0;
    monitor_.on_frame(f, now, events_);
    // A configured node that reboots while we run has lost its configuration.
    if (booted && running_ && node(nid) != nullptr && config_.quick_stop_on_fault) faulted_ = true;
    return;
  }
  if (id > cob::kEmcy && id <= cob::kEmcy + kMaxNodeId) {
    Event e;
    if (decode_emcy(f, e.emcy)) {
      e.type = EventType::kEmcy;
      e.node = e.emcy.node;
      e.value = e.emcy.code;
      e.time = now;
      events_.push(e);
      ++stats_.emcys;
    }
    return;
  }
  if (id > cob::kSdoTx && id <= cob::kSdoTx + kMaxNodeId) {
    if (NodeRt* n = node(static_cast<NodeId>(id - cob::kSdoTx))) n->sdo->on_frame(f, now);
    return;
  }
  const TpdoRef ref = tpdo_table_[id];
  if (ref.node >= 0) {
    NodeRt& n = *nodes_[static_cast<std::size_t>(ref.node)];
    if (n.tpdos[static_cast<std::size_t>(ref.pdo)].decode(f, n.image)) {
      ++stats_.tpdos_received;
      last_tpdo_[n.config.id] = now;
      if (n.drive >= 0) {
        Drive& d = drives_[static_cast<std::size_t>(n.drive)];
        for (const PdoLayout::Field& fld : n.tpdos[static_cast<std::size_t>(ref.pdo)].fields()) {
          if (d.carries_state(fld.slot)) {
            d.on_pdo();
            last_state_tpdo_[n.config.id] = now;
            break;
          }
        }
      }
      if (n.force >= 0) forces_[static_cast<std::size_t>(n.force)].on_pdo();
    } else {
      ++stats_.short_pdos;
    }
    return;
  }
  ++stats_.unknown_frames;
}

void Master::background(Timestamp now) {
  can::Frame f;
  if (heartbeat_.poll(now, own_state_, f)) send(f, now);
  monitor_.check(now, events_);
  for (auto& n : nodes_) {
    if (n->sdo->busy()) n->sdo->poll(now);
  }
}

void Master::cycle(Timestamp now) {
  receive(now);
  transmit(now);
}

void Master::receive(Timestamp now) {
  ++stats_.cycles;
  can::Frame f;
  // Bounded drain: a babbling node must not starve the cycle.
  for (int i = 0; i < 1024 && bus_.receive(f, std::chrono::nanoseconds(0)).ok(); ++i) {
    dispatch(f, now);
  }
  bus_sup_.on_stats(bus_.stats(), now, events_);
  monitor_.check(now, events_);
  for (auto& n : nodes_) {
    if (n->sdo->busy()) n->sdo->poll(now);
    if (config_.quick_stop_on_fault && running_ && n->config.heartbeat_timeout.count() > 0 &&
        monitor_.state(n->config.id) == NmtState::kLost) {
      faulted_ = true;
    }
  }
  for (Drive& d : drives_) {
    d.update(now);
    const auto& sup = d.supervisor();
    if (sup.became_faulted() || sup.became_stuck()) {
      Event e;
      e.type = sup.became_faulted() ? EventType::kDriveFault : EventType::kDriveStuck;
      e.node = d.node();
      e.value = d.statusword();
      e.time = now;
      events_.push(e);
      if (sup.became_faulted() && config_.quick_stop_on_fault) faulted_ = true;
    }
  }
  if (faulted_) {
    for (Drive& d : drives_) d.quick_stop();
  }
}

void Master::transmit(Timestamp now) {
  // What the caller asked of the drives since receive(): its targets and state requests.
  for (Drive& d : drives_) d.commit(now);
  can::Frame f;
  if (!bus_sup_.may_transmit(now, events_)) return;
  for (auto& n : nodes_) {
    for (const PdoLayout& l : n->rpdos) {
      l.encode(n->image, f);
      send(f, now);
      ++stats_.rpdos_sent;
    }
  }
  const std::uint64_t overruns = sync_.overruns();
  if (sync_.poll(now, f)) send(f, now);
  if (sync_.overruns() != overruns) {
    Event e;
    e.type = EventType::kSyncOverrun;
    e.value = static_cast<std::uint32_t>(sync_.overruns() - overruns);
    e.time = now;
    events_.push(e);
  }
  if (heartbeat_.poll(now, own_state_, f)) send(f, now);
}

void Master::pump_step() {
  const Timestamp now = hooks_.now();
  if (running_ && now >= next_cycle_) {
    cycle(now);
    next_cycle_ += config_.sync_period;
    if (next_cycle_ <= now) next_cycle_ = now + config_.sync_period;
    return;
  }
  can::Frame f;
  auto wait = hooks_.receive_timeout;
  if (running_ && next_cycle_ - now < wait) wait = next_cycle_ - now;
  if (bus_.receive(f, wait).ok()) {
    dispatch(f, hooks_.now());
  } else if (hooks_.idle) {
    hooks_.idle();
  }
  if (!running_) background(hooks_.now());
}

Status Master::wait_for(const std::function<bool()>& done, std::chrono::nanoseconds timeout,
                        const char* what) {
  const Timestamp start = hooks_.now();
  while (!done()) {
    if (hooks_.now() - start >= timeout) {
      return Status::error(ErrorCode::kTimeout, "%s: not done after %.0f ms", what, to_ms(timeout));
    }
    pump_step();
  }
  return Status::success();
}

Status Master::nmt(NmtCommand cmd, NodeId node_id) {
  const Timestamp now = hooks_.now();
  Status s = bus_.send(nmt_frame(cmd, node_id));
  if (!s.ok()) {
    return Status::error(ErrorCode::kIoError, "NMT %s to node %u: %.*s", to_string(cmd).data(),
                         unsigned{node_id}, static_cast<int>(s.message().size()),
                         s.message().data());
  }
  (void)now;
  return Status::success();
}

Status Master::boot() {
  running_ = false;
  own_state_ = NmtState::kPreOperational;
  // The master is a CANopen device too: its boot-up message comes before its first heartbeat
  // (CiA 301, 7.2.8.3.3).
  {
    const Status up = bus_.send(heartbeat_.boot_up());
    if (!up.ok()) {
      return Status::error(ErrorCode::kIoError, "master boot-up message: %.*s",
                           static_cast<int>(up.message().size()), up.message().data());
    }
  }
  // Take in what is already queued (old boot-ups) so that only fresh boot-ups count below.
  can::Frame stale;
  while (bus_.receive(stale, std::chrono::nanoseconds(0)).ok()) dispatch(stale, hooks_.now());
  std::vector<std::uint32_t> boots(nodes_.size());
  for (std::size_t i = 0; i < nodes_.size(); ++i) {
    boots[i] = monitor_.node(nodes_[i]->config.id).boot_count;
  }
  auto missing = [&](auto&& ok_fn) {
    std::string ids;
    for (std::size_t i = 0; i < nodes_.size(); ++i) {
      if (ok_fn(i)) continue;
      if (!ids.empty()) ids += ", ";
      ids += std::to_string(nodes_[i]->config.id) + " (" + nodes_[i]->config.name + ")";
    }
    return ids;
  };

  if (config_.reset_communication) {
    Status s = nmt(NmtCommand::kResetCommunication, 0);
    if (!s.ok()) return s;
    auto booted = [&](std::size_t i) {
      return monitor_.node(nodes_[i]->config.id).boot_count > boots[i];
    };
    s = wait_for([&] { return missing(booted).empty(); }, config_.boot_timeout, "boot-up");
    if (!s.ok()) {
      return Status::error(ErrorCode::kTimeout,
                           "node %s: no boot-up within %.0f ms after NMT reset communication",
                           missing(booted).c_str(), to_ms(config_.boot_timeout));
    }
  }
  for (auto& n : nodes_) {
    CDPR_RETURN_IF_ERROR(configure_node(n->config.id));
  }
  for (auto& n : nodes_) {
    CDPR_RETURN_IF_ERROR(nmt(NmtCommand::kStart, n->config.id));
  }
  auto operational = [&](std::size_t i) {
    const NodeConfig& c = nodes_[i]->config;
    return c.heartbeat_period.count() == 0 || monitor_.state(c.id) == NmtState::kOperational;
  };
  Status s =
      wait_for([&] { return missing(operational).empty(); }, config_.boot_timeout, "NMT start");
  if (!s.ok()) {
    return Status::error(ErrorCode::kTimeout,
                         "node %s: not OPERATIONAL within %.0f ms after NMT start",
                         missing(operational).c_str(), to_ms(config_.boot_timeout));
  }
  for (auto& n : nodes_) {
    if (n->config.heartbeat_timeout.count() > 0) {
      monitor_.consume(n->config.id, n->config.heartbeat_timeout);
    }
  }
  own_state_ = NmtState::kOperational;
  const Timestamp now = hooks_.now();
  sync_.start(now);
  next_cycle_ = now;
  running_ = true;
  return Status::success();
}

Status Master::configure_node(NodeId id) {
  NodeRt* n = node(id);
  if (n == nullptr) {
    return Status::error(ErrorCode::kNotFound, "node %u: not in the configuration", unsigned{id});
  }
  const NodeConfig& c = n->config;
  SdoClient& sdo = *n->sdo;
  if (c.heartbeat_period.count() > 0) {
    CDPR_RETURN_IF_ERROR(sdo.write<std::uint16_t>(
        {0x1017, 0}, static_cast<std::uint16_t>(std::lround(to_ms(c.heartbeat_period))), pump_));
  }
  if (c.master_heartbeat_timeout.count() > 0) {
    const auto ms = static_cast<std::uint32_t>(std::lround(to_ms(c.master_heartbeat_timeout)));
    CDPR_RETURN_IF_ERROR(sdo.write<std::uint32_t>(
        {0x1016, 1}, (std::uint32_t{config_.master_id} << 16) | ms, pump_));
  }
  // A SYNC with a counter byte needs the node's 0x1019 to agree, or it raises EMCY 0x8240 and
  // leaves OPERATIONAL (CiA 301, 7.5.2.22).
  if (config_.sync_counter_overflow >= 2) {
    CDPR_RETURN_IF_ERROR(
        sdo.write<std::uint8_t>({0x1019, 0}, config_.sync_counter_overflow, pump_));
  }
  if (c.kind == NodeKind::kCia402Drive) {
    CDPR_RETURN_IF_ERROR(sdo.write<std::int16_t>(cia402::obj::kAbortConnectionOption,
                                                 c.drive.abort_connection_option, pump_));
    if (c.drive.quick_stop_option) {
      CDPR_RETURN_IF_ERROR(sdo.write<std::int16_t>(cia402::obj::kQuickStopOption,
                                                   *c.drive.quick_stop_option, pump_));
    }
  }
  if (config_.disable_unused_pdos) {
    CDPR_RETURN_IF_ERROR(disable_unused_pdos(*n));
  }
  for (const auto* list : {&c.rpdos, &c.tpdos}) {
    for (const PdoConfig& p : *list) {
      CDPR_RETURN_IF_ERROR(configure_pdo(sdo, pump_, p));
    }
  }
  if (c.kind == NodeKind::kCia402Drive) {
    if (c.drive.profile_velocity != 0) {
      CDPR_RETURN_IF_ERROR(
          sdo.write<std::uint32_t>(cia402::obj::kProfileVelocity, c.drive.profile_velocity, pump_));
    }
    if (c.drive.profile_acceleration != 0) {
      CDPR_RETURN_IF_ERROR(sdo.write<std::uint32_t>(cia402::obj::kProfileAcceleration,
                                                    c.drive.profile_acceleration, pump_));
      CDPR_RETURN_IF_ERROR(sdo.write<std::uint32_t>(cia402::obj::kProfileDeceleration,
                                                    c.drive.profile_acceleration, pump_));
    }
    if (c.drive.mode == Mode::kHoming) {
      CDPR_RETURN_IF_ERROR(
          sdo.write<std::int8_t>(cia402::obj::kHomingMethod, c.drive.homing_method, pump_));
    }
  }
  for (const SdoWrite& w : c.sdo_writes) {
    std::uint8_t b[4];
    put_le(b, static_cast<std::uint32_t>(w.value), size_of(w.type));
    CDPR_RETURN_IF_ERROR(
        sdo.download(w.object, std::span<const std::uint8_t>(b, size_of(w.type)), pump_));
  }
  if (c.kind == NodeKind::kCia402Drive && c.drive.mode != Mode::kNone) {
    CDPR_RETURN_IF_ERROR(set_mode(id, c.drive.mode));
  }
  if (!c.eds_data) read_identity(*n);  // for its DCF
  return Status::success();
}

// Real drives ship with default PDO mappings enabled (often four TPDOs each); left alone they
// load the bus with frames nobody reads and make a foreign RPDO COB-ID act on the drive. Every
// PDO the node has (its EDS lists them; without one the four of the pre-defined connection set,
// skipping those the node says it lacks) that the configuration does not use is invalidated:
// COB-ID read, written back with bit 31 set if it was valid.
Status Master::disable_unused_pdos(NodeRt& n) {
  const NodeConfig& c = n.config;
  SdoClient& sdo = *n.sdo;
  n.disabled.clear();
  for (PdoDirection d : {PdoDirection::kRpdo, PdoDirection::kTpdo}) {
    const auto& used = d == PdoDirection::kRpdo ? c.rpdos : c.tpdos;
    for (int number : pdo_numbers(c, d)) {
      bool configured = false;
      for (const PdoConfig& p : used) configured = configured || p.number == number;
      if (configured) continue;
      PdoConfig p;
      p.direction = d;
      p.number = number;
      const ObjectAddress cob{p.comm_index(), 1};
      auto r = sdo.read<std::uint32_t>(cob, pump_);
      if (!r.ok()) {
        const std::uint32_t code = sdo.server_abort_code();
        if (!c.eds_data && (code == abort_code::kNoObject || code == abort_code::kNoSubIndex)) {
          continue;  // the node has fewer PDOs
        }
        return r.status();
      }
      if (*r & cob::kInvalidBit) continue;
      CDPR_RETURN_IF_ERROR(sdo.write<std::uint32_t>(cob, *r | cob::kInvalidBit, pump_));
      n.disabled.push_back(p.comm_index());
      ++stats_.pdos_disabled;
    }
  }
  return Status::success();
}

void Master::restart_link(void* self) {
  auto* m = static_cast<Master*>(self);
  if (!m->link_) return;
  const can::RecoveryOutcome o = m->link_->recover();
  Event e;
  e.time = m->hooks_.now();
  if (o.action == can::RecoveryOutcome::Action::kFailed) {
    ++m->stats_.link_restart_failures;
    e.type = EventType::kLinkRestartFailed;
    e.value = static_cast<std::uint32_t>(o.error);
  } else {
    ++m->stats_.link_restarts;
    e.type = EventType::kLinkRestarted;
    e.value = static_cast<std::uint32_t>(o.action);
  }
  m->events_.push(e);
}

Status Master::enable_link_restart() {
  auto link = can::CanLink::open(config_.interface);
  if (!link.ok()) return link.status();
  can::LinkInfo info;
  CDPR_RETURN_IF_ERROR((*link)->query(info));
  link_ = std::move(*link);
  bus_sup_.set_restart_hook(&Master::restart_link, this);
  return Status::success();
}

Status Master::set_mode(NodeId id, Mode mode) {
  NodeRt* n = node(id);
  if (n == nullptr || n->drive < 0) {
    return Status::error(ErrorCode::kNotFound, "node %u: not a configured cia402 drive",
                         unsigned{id});
  }
  SdoClient& sdo = *n->sdo;
  Drive& drive = drives_[static_cast<std::size_t>(n->drive)];
  // Hold the position while the drive switches: whichever mode it is in meanwhile, the target
  // follows the actual position and no command of the old mode is carried over.
  drive.set_mode(Mode::kNone);
  const DriveConfig& dc = n->config.drive;
  if (mode == Mode::kCyclicSyncPosition && !has(dc, DriveQuirk::kNoInterpolationPeriod)) {
    // 0x60C2 interpolation time period = value * 10^index s, equal to the SYNC period.
    const double ms = to_ms(config_.sync_period);
    std::int8_t exponent = -3;
    double value = ms;
    while (std::abs(value - std::round(value)) > 1e-9 && exponent > -6) {
      value *= 10;
      --exponent;
    }
    if (value > 255) {
      return Status::error(ErrorCode::kOutOfRange,
                           "node %u: SYNC period %.4f ms does not fit 0x60C2 (u8 value)",
                           unsigned{id}, ms);
    }
    CDPR_RETURN_IF_ERROR(sdo.write<std::uint8_t>(cia402::obj::kInterpolationPeriodValue,
                                                 static_cast<std::uint8_t>(std::lround(value)),
                                                 pump_));
    CDPR_RETURN_IF_ERROR(
        sdo.write<std::int8_t>(cia402::obj::kInterpolationPeriodIndex, exponent, pump_));
  }
  CDPR_RETURN_IF_ERROR(sdo.write<std::int8_t>(cia402::obj::kModesOfOperation,
                                              static_cast<std::int8_t>(mode), pump_));
  const Timestamp start = hooks_.now();
  const auto timeout = n->config.drive.mode_switch_timeout;
  std::int8_t shown = 0;
  // Quirk no_mode_display: the drive's 0x6061 does not follow, 0x6060 read back stands for it.
  const bool display = !has(dc, DriveQuirk::kNoModeDisplay);
  for (;;) {
    auto r = sdo.read<std::int8_t>(
        display ? cia402::obj::kModesDisplay : cia402::obj::kModesOfOperation, pump_);
    if (!r.ok()) return r.status();
    shown = *r;
    if (shown == static_cast<std::int8_t>(mode)) break;
    if (hooks_.now() - start >= timeout) {
      return Status::error(ErrorCode::kTimeout,
                           "node %u: 0x%04X shows mode %d %.0f ms after writing 0x6060 = %d (%s)",
                           unsigned{id}, display ? 0x6061u : 0x6060u, int{shown}, to_ms(timeout),
                           static_cast<int>(mode), to_string(mode).data());
    }
    const Timestamp until = hooks_.now() + std::chrono::milliseconds(10);
    (void)wait_for([&] { return hooks_.now() >= until; }, std::chrono::seconds(1), "mode poll");
  }
  drive.set_mode(mode);
  return Status::success();
}

Status Master::set_actual_position(NodeId id, double position, std::chrono::nanoseconds timeout) {
  NodeRt* n = node(id);
  if (n == nullptr || n->drive < 0) {
    return Status::error(ErrorCode::kNotFound, "node %u: not a configured cia402 drive",
                         unsigned{id});
  }
  return set_actual_counts(id, drives_[static_cast<std::size_t>(n->drive)].to_counts(position),
                           timeout);
}

Status Master::set_actual_counts(NodeId id, std::int32_t counts, std::chrono::nanoseconds timeout) {
  NodeRt* n = node(id);
  if (n == nullptr || n->drive < 0) {
    return Status::error(ErrorCode::kNotFound, "node %u: not a configured cia402 drive",
                         unsigned{id});
  }
  Drive& drive = drives_[static_cast<std::size_t>(n->drive)];
  if (!running_) {
    return Status::error(ErrorCode::kFailedPrecondition,
                         "node %u: set actual position: the master is not running", unsigned{id});
  }
  if (!drive.enabled()) {
    return Status::error(ErrorCode::kFailedPrecondition,
                         "node %u: set actual position needs OPERATION_ENABLED (drive in %s)",
                         unsigned{id}, cia402::to_string(drive.state()).data());
  }
  if (const auto& e = n->config.eds_data; e && (e->find(cia402::obj::kHomingMethod) == nullptr ||
                                                e->find(cia402::obj::kHomeOffset) == nullptr)) {
    return Status::error(ErrorCode::kFailedPrecondition,
                         "node %u: set actual position needs the drive's homing, but %s has no "
                         "0x6098 (homing method) or 0x607C (home offset)",
                         unsigned{id}, e->source().c_str());
  }
  const Mode previous = drive.mode();
  const std::int8_t method = n->config.drive.homing_method == 35 ? 35 : 37;
  SdoClient& sdo = *n->sdo;
  Status s = sdo.write<std::int8_t>(cia402::obj::kHomingMethod, method, pump_);
  if (!s.ok()) return s;
  s = sdo.write<std::int32_t>(cia402::obj::kHomeOffset, counts, pump_);
  if (!s.ok()) return s;
  s = set_mode(id, Mode::kHoming);
  if (!s.ok()) return s;
  drive.start_homing();
  const Timestamp t0 = hooks_.now();
  s = wait_for([&] { return drive.homing_done() || drive.homing_error() || !drive.enabled(); },
               timeout, "homing");
  if (drive.homing_error() || !drive.enabled() || !s.ok()) {
    const char* what = drive.homing_error() ? "reported a homing error"
                       : !drive.enabled()   ? "left OPERATION_ENABLED"
                                            : "did not report homing attained";
    return Status::error(s.ok() ? ErrorCode::kUnavailable : ErrorCode::kTimeout,
                         "node %u: homing method %d to %d counts: %s after %.0f ms (statusword "
                         "0x%04X)",
                         unsigned{id}, int{method}, counts, what, to_ms(hooks_.now() - t0),
                         unsigned{drive.statusword()});
  }
  if (drive.actual_counts() != counts) {
    return Status::error(ErrorCode::kProtocolError,
                         "node %u: position actual is %d counts after homing, expected %d",
                         unsigned{id}, drive.actual_counts(), counts);
  }
  if (previous != Mode::kNone && previous != Mode::kHoming) return set_mode(id, previous);
  return Status::success();
}

void Master::quick_stop_all() {
  for (Drive& d : drives_) d.quick_stop();
}

Status Master::enable_all(std::chrono::nanoseconds timeout) {
  if (!running_) return Status(ErrorCode::kFailedPrecondition, "enable: the master is not running");
  for (Drive& d : drives_) d.enable();
  Status err;
  auto done = [&] {
    bool all = true;
    for (const Drive& d : drives_) {
      const auto& sup = d.supervisor();
      if (sup.stuck() || (sup.in_fault() && d.received() && !sup.fault_reset_pending())) {
        err = d.supervisor().error();
        if (err.ok())
          err =
              Status::error(ErrorCode::kUnavailable, "node %u: drive in fault", unsigned{d.node()});
        return true;
      }
      all = all && d.enabled();
    }
    return all;
  };
  Status s = wait_for(done, timeout, "enable");
  if (!err.ok()) return err;
  if (!s.ok()) {
    for (const Drive& d : drives_) {
      if (!d.enabled()) {
        return Status::error(
            ErrorCode::kTimeout, "node %u: not OPERATION_ENABLED after %.0f ms (in %s)",
            unsigned{d.node()}, to_ms(timeout), cia402::to_string(d.state()).data());
      }
    }
  }
  return s;
}

BusLoad Master::bus_load() const {
  return canopen::bus_load(config_);
}

BusLoad bus_load(const MasterConfig& config) {
  std::vector<PeriodicFrame> frames;
  const double cycle_ms = to_ms(config.sync_period);
  frames.push_back({static_cast<std::uint8_t>(config.sync_counter_overflow >= 2 ? 1 : 0), 1.0});
  auto per_cycle = [&](const PdoConfig& p) {
    if (p.transmission_type >= 1 && p.transmission_type <= 240) return 1.0 / p.transmission_type;
    if (p.transmission_type >= 254 && p.event_timer_ms > 0) return cycle_ms / p.event_timer_ms;
    return 1.0;  // acyclic or event driven without timer: assume once per cycle (worst case)
  };
  for (const NodeConfig& n : config.nodes) {
    for (const auto* list : {&n.rpdos, &n.tpdos}) {
      for (const auto& p : *list) {
        if (p.entries.empty()) continue;
        frames.push_back({static_cast<std::uint8_t>(p.byte_size()), per_cycle(p)});
      }
    }
    if (n.heartbeat_period.count() > 0) {
      frames.push_back({1, cycle_ms / to_ms(n.heartbeat_period)});
    }
  }
  if (config.master_heartbeat_period.count() > 0) {
    frames.push_back({1, cycle_ms / to_ms(config.master_heartbeat_period)});
  }
  return compute_bus_load(frames, config.sync_period, config.bitrate, config.bus_load_warning);
}

}  // namespace cdpr::canopen
