#include "cdpr/controller/measuring_sequence.hpp"

#include <limits>
#include <string>
#include <utility>

namespace cdpr::controller {

namespace {
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
}  // namespace

const char* to_string(MeasuringStep s) {
  switch (s) {
    case MeasuringStep::kMove:
      return "move";
    case MeasuringStep::kSettle:
      return "settle";
    case MeasuringStep::kRegulate:
      return "regulate";
    case MeasuringStep::kSample:
      return "sample";
    case MeasuringStep::kAppend:
      return "append";
    case MeasuringStep::kNext:
      return "next";
    case MeasuringStep::kReturn:
      return "return";
    case MeasuringStep::kDone:
      return "done";
  }
  return "?";
}

MeasuringSequence::MeasuringSequence(MeasuringRobot& robot, recording::RecordingAppender recording)
    : robot_(robot), out_(std::move(recording)), t0_(robot.now_s()) {}

void MeasuringSequence::add_round(std::vector<Pose> poses, std::vector<double> pretensions) {
  pretensions.resize(poses.size(), kNaN);
  cursor_ = poses_.size();
  poses_.insert(poses_.end(), poses.begin(), poses.end());
  pretensions_.insert(pretensions_.end(), pretensions.begin(), pretensions.end());
  step_ = cursor_ < poses_.size() ? MeasuringStep::kMove : MeasuringStep::kReturn;
}

Status MeasuringSequence::step_pose() {
  const Pose& pose = poses_[cursor_];
  const double pre = pretensions_[cursor_];
  const int index = static_cast<int>(cursor_);
  switch (step_) {
    case MeasuringStep::kMove:
      CDPR_RETURN_IF_ERROR(robot_.move(pose, pre));
      step_ = MeasuringStep::kSettle;
      return Status::success();
    case MeasuringStep::kSettle:
      CDPR_RETURN_IF_ERROR(robot_.settle());
      step_ = MeasuringStep::kRegulate;
      return Status::success();
    case MeasuringStep::kRegulate:
      CDPR_RETURN_IF_ERROR(robot_.regulate(index));
      step_ = MeasuringStep::kSample;
      return Status::success();
    case MeasuringStep::kSample:
      row_ = recording::RecordedPose{};
      row_.index = index;
      CDPR_RETURN_IF_ERROR(robot_.sample(row_));
      row_.commanded = pose;
      row_.time_s = robot_.now_s() - t0_;
      step_ = MeasuringStep::kAppend;
      return Status::success();
    default:
      return Status::success();
  }
}

Status MeasuringSequence::step() {
  switch (step_) {
    case MeasuringStep::kMove:
    case MeasuringStep::kSettle:
    case MeasuringStep::kRegulate:
    case MeasuringStep::kSample:
      if (Status s = step_pose(); !s.ok()) {
        return s.prepend("pose " + std::to_string(cursor_) + ": ");
      }
      return Status::success();
    case MeasuringStep::kAppend: {
      CDPR_RETURN_IF_ERROR(out_.append(row_));
      const double elapsed = robot_.now_s() - t0_;
      const int done = static_cast<int>(cursor_) + 1;
      const int total = static_cast<int>(poses_.size());
      const double remaining = done < total ? elapsed / done * (total - done) : 0.0;
      robot_.measured(row_, done, total, elapsed, remaining);
      step_ = MeasuringStep::kNext;
      return Status::success();
    }
    case MeasuringStep::kNext:
      ++cursor_;
      step_ = cursor_ < poses_.size() ? MeasuringStep::kMove : MeasuringStep::kReturn;
      return Status::success();
    case MeasuringStep::kReturn:
      // Back to where the calibration started (home for a designed set) while the worker
      // identifies and the result awaits the operator: a designed pose sits near the tension
      // limits of the geometry that is about to change, and a hot swap there (accept, reject's
      // rollback later) may leave one geometry no feasible tension distribution or a cable slack.
      if (Status s = robot_.move(poses_.front(), kNaN); !s.ok()) {
        return s.prepend("back to the first pose: ");
      }
      step_ = MeasuringStep::kDone;
      return Status::success();
    case MeasuringStep::kDone:
      return Status::success();
  }
  return Status::success();
}

Status MeasuringSequence::run_round() {
  while (step_ != MeasuringStep::kDone) CDPR_RETURN_IF_ERROR(step());
  return Status::success();
}

}  // namespace cdpr::controller
