// RtController's tension-control stage (tension_control.hpp): runs while holding or moving, on
// this cycle's readings and the plan and kinematics of the pose commanded last; its trims enter
// the drive targets in slew_targets. Frozen (then decaying) while a force fault is latched; held
// while the measuring sequence asks (hold_tension_trims).
#include "cdpr/controller/rt_controller.hpp"

namespace cdpr::controller {

void RtController::control_tensions() noexcept {
  const bool run = mode_ == RtMode::kHolding || mode_ == RtMode::kMoving;
  const bool sensor_fault =
      fault_.kind == FaultKind::kForceStuck || fault_.kind == FaultKind::kForceSensor;
  const bool hold = hold_tension_trims_.load(std::memory_order_acquire);
  tension_.step(run, hold, sensor_fault, in_, geometry_->model, command_data_);
}

}  // namespace cdpr::controller
