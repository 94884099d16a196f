#include "cdpr/canopen/devices.hpp"

#include <cmath>
#include <limits>

namespace cdpr::canopen {

Result<Drive> Drive::bind(const NodeConfig& config, ProcessImage& image) {
  Drive d;
  d.node_ = config.id;
  d.image_ = &image;
  d.counts_per_unit_ = config.drive.counts_per_unit;
  d.sup_ = cia402::Supervisor(config.id, config.drive.transition_timeout);
  struct Need {
    ObjectAddress obj;
    std::uint16_t* slot;
  };
  const Need needs[] = {{cia402::obj::kControlword, &d.cw_slot_},
                        {cia402::obj::kTargetPosition, &d.target_slot_},
                        {cia402::obj::kStatusword, &d.sw_slot_},
                        {cia402::obj::kPositionActual, &d.actual_slot_}};
  for (const auto& n : needs) {
    const int s = image.find(n.obj);
    if (s < 0) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "node %u: drive PDOs do not map 0x%04X:%02X", unsigned{config.id},
                           unsigned{n.obj.index}, unsigned{n.obj.sub});
    }
    *n.slot = static_cast<std::uint16_t>(s);
  }
  return d;
}

std::int32_t Drive::to_counts(double x) const {
  const double c = std::round(x * counts_per_unit_);
  constexpr double lo = std::numeric_limits<std::int32_t>::min();
  constexpr double hi = std::numeric_limits<std::int32_t>::max();
  return static_cast<std::int32_t>(c < lo ? lo : (c > hi ? hi : c));
}

bool Drive::set_target_counts(std::int32_t counts) {
  if (!enabled() || mode_ != Mode::kCyclicSyncPosition) return false;
  user_target_ = counts;
  user_target_valid_ = true;
  return true;
}

void Drive::set_mode(Mode m) {
  mode_ = m;
  user_target_valid_ = false;
  pp_pending_ = pp_bit4_ = false;
  pp_reached_ = true;
  homing_requested_ = false;
  target_ = actual_;
}

bool Drive::move_to_counts(std::int32_t counts) {
  if (!enabled() || mode_ != Mode::kProfilePosition) return false;
  pp_target_ = counts;
  pp_pending_ = true;
  pp_reached_ = false;
  return true;
}

void Drive::update(Timestamp now) {
  if (!received_) {
    image_->set(cw_slot_, cia402::cw::kDisableVoltage);
    return;
  }
  statusword_ = static_cast<std::uint16_t>(image_->get(sw_slot_));
  actual_ = static_cast<std::int32_t>(image_->get(actual_slot_));
  std::uint16_t c = sup_.step(statusword_, now);
  const bool en = enabled();

  if (!en) {
    // Not enabled: the target tracks the actual position so that enabling never jumps, and
    // stale commands are dropped.
    target_ = actual_;
    user_target_valid_ = false;
    pp_pending_ = pp_bit4_ = false;
    pp_reached_ = true;
  } else {
    if (!was_enabled_) {
      ++enable_count_;
      const std::int64_t err = std::llabs(std::int64_t{target_} - actual_);
      if (err > max_enable_error_) max_enable_error_ = err;
    }
    switch (mode_) {
      case Mode::kCyclicSyncPosition:
        if (user_target_valid_) target_ = user_target_;
        break;
      case Mode::kProfilePosition:
        if (pp_pending_ && !pp_bit4_ && !(statusword_ & cia402::sw::kSetPointAcknowledge)) {
          target_ = pp_target_;
          pp_bit4_ = true;
        } else if (pp_bit4_ && (statusword_ & cia402::sw::kSetPointAcknowledge)) {
          pp_bit4_ = false;  // the drive took the set-point: complete the handshake
          pp_pending_ = false;
        }
        if (!pp_pending_ && !pp_bit4_ && !(statusword_ & cia402::sw::kSetPointAcknowledge)) {
          pp_reached_ = (statusword_ & cia402::sw::kTargetReached) != 0;
        }
        if (pp_bit4_) c |= cia402::cw::kNewSetPoint | cia402::cw::kChangeImmediately;
        break;
      case Mode::kHoming:
        if (homing_requested_) {
          if (homing_cycles_ < 0) {
            homing_cycles_ = 0;  // bit 4 low for one cycle: the next one is an edge
          } else {
            // The statusword of the SYNC after the edge was applied is the first to count
            // (a drive may sample its TPDO before it applies the RPDO of the same SYNC).
            if (homing_cycles_ >= 2) {
              if (statusword_ & cia402::sw::kHomingError) {
                homing_error_ = true;
                homing_requested_ = false;
              } else if ((statusword_ & cia402::sw::kHomingAttained) &&
                         (statusword_ & cia402::sw::kTargetReached)) {
                homing_done_ = true;
                homing_requested_ = false;
              }
            }
            if (homing_cycles_ < 1000) ++homing_cycles_;
            c |= cia402::cw::kStartHoming;
          }
        }
        target_ = actual_;
        break;
      case Mode::kNone:
        target_ = actual_;
        break;
    }
  }
  was_enabled_ = en;
  controlword_ = c;
  image_->set(cw_slot_, c);
  image_->set(target_slot_, target_);
  stepped_target_ = sup_.target();
  stepped_reset_ = sup_.fault_reset_pending();
  stepped_stuck_ = sup_.stuck();
}

void Drive::commit(Timestamp now) {
  if (!received_) return;
  if (sup_.target() != stepped_target_ || sup_.fault_reset_pending() != stepped_reset_ ||
      sup_.stuck() != stepped_stuck_) {
    // Same statusword, new request: the state bits follow it, the mode bits stay as update()
    // made them (the state, and so enabled(), does not change).
    const std::uint16_t state_bits = sup_.step(statusword_, now);
    controlword_ =
        static_cast<std::uint16_t>(state_bits | (controlword_ & ~cia402::cw::kStateMask));
    stepped_target_ = sup_.target();
    stepped_reset_ = sup_.fault_reset_pending();
    stepped_stuck_ = sup_.stuck();
  }
  if (enabled() && mode_ == Mode::kCyclicSyncPosition && user_target_valid_) target_ = user_target_;
  image_->set(cw_slot_, controlword_);
  image_->set(target_slot_, target_);
}

Result<ForceSensor> ForceSensor::bind(const NodeConfig& config, const ProcessImage& image) {
  ForceSensor f;
  f.node_ = config.id;
  f.image_ = &image;
  for (const auto& p : config.tpdos) {
    for (const auto& e : p.entries) {
      const int s = image.find(e.object);
      if (s < 0) {
        return Status::error(ErrorCode::kInternal, "node %u: channel 0x%04X:%02X not in image",
                             unsigned{config.id}, unsigned{e.object.index}, unsigned{e.object.sub});
      }
      f.slots_.push_back(static_cast<std::uint16_t>(s));
    }
  }
  f.gain_ = config.force.gain;
  f.offset_ = config.force.offset;
  if (f.gain_.size() != f.slots_.size() || f.offset_.size() != f.slots_.size()) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "node %u: %zu channels but %zu gains and %zu offsets", unsigned{config.id},
                         f.slots_.size(), f.gain_.size(), f.offset_.size());
  }
  return f;
}

}  // namespace cdpr::canopen
