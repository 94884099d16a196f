// Master::shutdown: the orderly end of the master's life on the bus (docs/canopen.md, shutdown).
#include <string>

#include "cdpr/canopen/master.hpp"

namespace cdpr::canopen {

namespace {

// Every drive that reports has reached the requested state (or is in fault).
bool all_reached(std::span<const Drive> drives) {
  for (const Drive& d : drives) {
    if (d.received() && !d.supervisor().reached() && !d.supervisor().in_fault()) return false;
  }
  return true;
}

}  // namespace

// A node consuming our heartbeat (0x1016) applies its abort connection option (0x6007; 1 = fault)
// when the heartbeat stops, which it does when the master exits. NMT does not prevent that: the
// heartbeat consumer stays active in PRE-OPERATIONAL and STOPPED (CiA 301 error control), and
// entering STOPPED is itself an abort-connection event of CiA 402. A consumer time of 0 disables
// the entry (CiA 301, 0x1016), so the master writes 0x1016:01 = 0 to every node it configured as
// a consumer, once the drives are disabled. The next boot writes it again.
Status Master::stop_heartbeat_consumers() {
  Status first;
  for (auto& n : nodes_) {
    const NodeConfig& c = n->config;
    if (c.master_heartbeat_timeout.count() <= 0) continue;
    if (monitor_.state(c.id) == NmtState::kLost) continue;  // nobody to tell (and no wait)
    Status s = n->sdo->write<std::uint32_t>({0x1016, 1}, 0, pump_);
    if (!s.ok() && first.ok()) {
      first = Status::error(s.code(), "node %u (%s): consumer heartbeat 0x1016:01 = 0: %s",
                            unsigned{c.id}, c.name.c_str(), std::string(s.message()).c_str());
    }
  }
  return first;
}

Status Master::shutdown(std::chrono::nanoseconds timeout) {
  Status first;
  if (running_) {
    quick_stop_all();
    Status s = wait_for([&] { return all_reached(drives_); }, timeout, "quick stop of the drives");
    if (!s.ok()) first = s;
    for (Drive& d : drives_) d.disable();
    s = wait_for([&] { return all_reached(drives_); }, timeout, "disable voltage of the drives");
    if (!s.ok() && first.ok()) first = s;
  }
  // While the master still cycles (heartbeat, SYNC): the nodes stop watching it.
  Status s = stop_heartbeat_consumers();
  if (!s.ok() && first.ok()) first = s;
  running_ = false;
  sync_.stop();
  own_state_ = NmtState::kPreOperational;
  s = nmt(NmtCommand::kEnterPreOperational, 0);
  if (!s.ok() && first.ok()) first = s;
  return first;
}

}  // namespace cdpr::canopen
