// The measuring sequence of a calibration, in steps (docs/daemon.md "The measuring sequence"):
//
//   for each pose of a round:  move → settle → regulate → sample → append → next
//   after the round's last:    return (to the calibration's first pose), then done
//
// It owns the recording: each row is appended to the file and made durable as it is measured
// (recording::RecordingAppender), and the identification reads the rows from recording() — the
// file is never read back. What it asks of the robot is MeasuringRobot: the daemon implements it
// on the RT loop (each call waits until the robot is there); a test fakes it.
//
//   MeasuringSequence seq(robot, recording::RecordingAppender(path, header));
//   seq.add_round(poses, {});           // then extra poses, poses measured again: more rounds
//   CDPR_RETURN_IF_ERROR(seq.run_round());
//   auto set = recording::to_measurement_set(seq.recording());
#pragma once

#include <vector>

#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/recording/recording.hpp"
#include "cdpr/status.hpp"

namespace cdpr::controller {

class MeasuringRobot {
 public:
  virtual ~MeasuringRobot() = default;
  // To `pose`, planned at `pretension` N (NaN: the geometry's reference tension).
  virtual Status move(const Pose& pose, double pretension) = 0;
  // Until the platform and the tensions are still.
  virtual Status settle() = 0;
  // The tensions into their planned band (the row's index names the pose in messages).
  virtual Status regulate(int pose_index) = 0;
  // Averages the encoders and tensions and reads the laser into `row` (lengths, tensions, lasers,
  // reference); the sequence sets its index, commanded pose and time.
  virtual Status sample(recording::RecordedPose& row) = 0;
  virtual double now_s() const = 0;
  // After each row is appended: `done` rows of `total` planned so far, times since the start.
  virtual void measured(const recording::RecordedPose& row, int done, int total, double elapsed_s,
                        double remaining_s) = 0;
};

enum class MeasuringStep { kMove, kSettle, kRegulate, kSample, kAppend, kNext, kReturn, kDone };
const char* to_string(MeasuringStep s);

class MeasuringSequence {
 public:
  // The sequence's clock starts now (rows' time_s and the progress count from it).
  MeasuringSequence(MeasuringRobot& robot, recording::RecordingAppender recording);

  // A round of poses, measured at `pretensions` (missing or NaN: the reference tension), as the
  // next rows. The first round's first pose is where every round returns to.
  void add_round(std::vector<Pose> poses, std::vector<double> pretensions);
  // Runs the step next() names and moves on. An error leaves the sequence at that step; its
  // message starts with "pose N: " (move to sample) or "back to the first pose: " (return).
  Status step();
  // Steps until the round is done.
  Status run_round();

  MeasuringStep next() const { return step_; }
  const recording::Recording& recording() const { return out_.recording(); }
  const std::string& path() const { return out_.path(); }
  // Every pose planned so far, in row order, and the pretension each row was measured at.
  const std::vector<Pose>& poses() const { return poses_; }
  double pretension(int row) const { return pretensions_[static_cast<std::size_t>(row)]; }
  double started_s() const { return t0_; }

 private:
  Status step_pose();

  MeasuringRobot& robot_;
  recording::RecordingAppender out_;
  double t0_;
  std::vector<Pose> poses_;          // every pose planned (rows, then the round in progress)
  std::vector<double> pretensions_;  // per planned pose
  std::size_t cursor_ = 0;           // the pose being measured
  recording::RecordedPose row_;      // its row
  MeasuringStep step_ = MeasuringStep::kDone;
};

}  // namespace cdpr::controller
