// Calibration recordings and pre-calibration experiments as CSV files (docs/recording-format.md).
//
// Three file kinds share one syntax: `# key: value` metadata lines, then a header row, then one
// row of comma-separated numbers per sample. Every reader checks every row and names the file,
// line and column of the first bad cell; every writer writes the shortest decimal that reads back
// to the same double (std::to_chars), so write -> read is exact.
//
// - Recording: one row per measured pose (commanded pose, cable lengths, tensions, laser
//   distances, optional reference pose and temperature). Empty cells are "not measured" (NaN).
// - CableExperiment: (length_m, tension_n, elongation_m) samples for the elongation surface fit.
// - ForceSensorExperiment: (channel, mass_kg, raw) samples for the force-sensor gain/offset fit.
//
// SI units everywhere (m, rad, N, s, kg; temperature in degrees Celsius). A file must state
// `# units: SI`; readers refuse any other statement or none, so a file written in mm is caught.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <limits>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "cdpr/calibration/measurement.hpp"
#include "cdpr/calibration/robot_model.hpp"
#include "cdpr/io/append_only_file.hpp"
#include "cdpr/status.hpp"

namespace cdpr::recording {

inline constexpr std::string_view kUnitsSI = "SI";

struct PoseList;

// Ordered `# key: value` lines. Keys are unique; writers keep the order they were added in.
class Metadata {
 public:
  // Sets (or replaces) a value.
  void set(std::string key, std::string value);
  // Sets a number, written so it reads back exactly.
  void set_number(std::string key, double value);
  bool has(std::string_view key) const;
  // The value, or "" when absent.
  std::string get(std::string_view key) const;
  // The value as a number; an error names the key when it is absent or not a number.
  Result<double> number(std::string_view key) const;
  const std::vector<std::pair<std::string, std::string>>& entries() const { return entries_; }
  bool operator==(const Metadata&) const = default;

 private:
  std::vector<std::pair<std::string, std::string>> entries_;
};

// Well-known metadata keys (writers set those they know; readers only require `units`).
namespace key {
inline constexpr const char* kFormat = "format";               // "cdpr-recording 1", ...
inline constexpr const char* kUnits = "units";                 // must be "SI"
inline constexpr const char* kRobot = "robot";                 // RobotModel::name
inline constexpr const char* kDate = "date";                   // ISO 8601, UTC
inline constexpr const char* kConfigFile = "config_file";      // path of the robot config
inline constexpr const char* kConfigHash = "config_hash";      // "fnv1a64:<16 hex digits>"
inline constexpr const char* kNoiseLength = "noise_length_m";  // std dev of length_i, m
inline constexpr const char* kNoiseForce = "noise_force_n";    // std dev of tension_i, N
inline constexpr const char* kNoiseLaser = "noise_laser_m";    // std dev of laser_j, m
inline constexpr const char* kNoiseRefPosition = "noise_reference_position_m";  // m
inline constexpr const char* kNoiseRefAngle = "noise_reference_angle_rad";      // rad
inline constexpr const char* kNoiseSwivel = "noise_swivel_rad";                 // swivel_i, rad
inline constexpr const char* kNoiseInclination = "noise_inclination_rad";       // incl_*, rad
inline constexpr const char* kNoiseImuYaw = "noise_imu_yaw_rad";                // imu_yaw, rad
inline constexpr const char* kSeed = "seed";      // simulator seed, if simulated
inline constexpr const char* kSource = "source";  // "simulated", "robot", "hand-made"
}  // namespace key

// One measured pose. Vectors hold NaN where a cell was empty (not measured).
struct RecordedPose {
  std::int64_t index = 0;    // the `pose` column; strictly increasing through a file
  double time_s = 0.0;       // s since the start of the recording
  Pose commanded;            // cmd_x..cmd_z (m), cmd_roll..cmd_yaw (rad)
  Eigen::VectorXd lengths;   // m entries, m
  Eigen::VectorXd tensions;  // m entries, N
  Eigen::VectorXd lasers;    // k entries, m
  Eigen::VectorXd swivels;   // m entries when the file has swivel_ columns, rad
  Eigen::Vector2d inclination = Eigen::Vector2d::Constant(std::numeric_limits<double>::quiet_NaN());
  double imu_yaw = std::numeric_limits<double>::quiet_NaN();  // rad
  Pose reference;  // ref_*; NaN when not measured (or when the file has no ref_ columns)
  double temperature_c = std::numeric_limits<double>::quiet_NaN();  // degrees Celsius
  // What a real campaign knows besides the readings (optional columns, docs/recording-format.md).
  Eigen::VectorXd planned_tensions;  // m entries when the file has planned_tension_ columns, N
  double scatter_length_m = std::numeric_limits<double>::quiet_NaN();  // this pose's, m
  double scatter_force_n = std::numeric_limits<double>::quiet_NaN();   // this pose's, N
  bool supported = false;  // the platform rested on something: the cables did not carry it all
  Pose start;              // start_*; NaN when not given (or when the file has no start_ columns)
  int line = 0;            // the row's line in the file it was read from (1-based); 0 when not read
};

struct Recording {
  Metadata metadata;
  int num_cables = 0;                 // m >= 1
  int num_lasers = 0;                 // k >= 0 (0: no laser columns)
  bool has_swivel = false;            // the file has swivel_1..swivel_m
  bool has_inclinometer = false;      // the file has incl_roll and incl_pitch
  bool has_imu_yaw = false;           // the file has imu_yaw
  bool has_reference = false;         // the file has the six ref_* columns
  bool has_temperature = false;       // the file has the temperature_c column
  bool has_planned_tensions = false;  // the file has planned_tension_1..planned_tension_m
  bool has_scatter_length = false;    // the file has scatter_length_m
  bool has_scatter_force = false;     // the file has scatter_force_n
  bool has_supported = false;         // the file has supported
  bool has_start = false;             // the file has the six start_* columns
  std::vector<RecordedPose> poses;
  std::vector<std::string> header;  // the column names in the file's order; empty when not read
};

// Reads and checks a recording. Errors: kNotFound/kIoError (file), kParseError (syntax; the
// message is "<file>:<line>: column <c> (<name>): <reason>" or "<file>:<line>: <reason>").
Result<Recording> read_recording(const std::string& path);
// Same, from text in memory; `name` stands for the file in messages.
Result<Recording> parse_recording(std::string_view text, std::string_view name);
// Writes the canonical form (columns in the documented order). Refuses inconsistent sizes,
// non-increasing pose indices and infinite values.
Status write_recording(const Recording& recording, const std::string& path);
Result<std::string> format_recording(const Recording& recording);
// The two parts of that text: the header block (metadata and column names; the poses are not
// used) and one row of `recording`'s columns (sizes and finiteness checked as above).
Result<std::string> format_recording_header(const Recording& recording);
Result<std::string> format_recording_row(const Recording& recording, const RecordedPose& pose);

// A recording written as it is measured (cdprd's sequence): each row is appended and made durable
// (fdatasync) before append() returns, the file being created with the header block at the first
// row, so that the file always equals write_recording()'s output for the rows appended so far. A
// crash loses at most the row being written; cut_torn_row() removes what it left (part of a row
// without its newline) before the file is read again. Nothing is read back: recording() holds
// the header and every row appended.
//
//   RecordingAppender out(dir + "/recording.csv", header);   // header: metadata and columns
//   CDPR_RETURN_IF_ERROR(out.append(row));
//   auto set = to_measurement_set(out.recording());
class RecordingAppender {
 public:
  RecordingAppender(std::string path, Recording header);

  // Refuses a row whose index does not increase or whose sizes do not fit the columns (nothing
  // is written then).
  Status append(const RecordedPose& row);
  const Recording& recording() const { return recording_; }
  const std::string& path() const { return file_path_; }

  // Cuts a torn last row (bytes after the last newline) off `path`; returns how many bytes were
  // cut (0: the file ends with a newline, is empty or does not exist).
  static Result<std::size_t> cut_torn_row(const std::string& path);

 private:
  std::string file_path_;
  Recording recording_;
  io::AppendOnlyFile file_;
};

// Checks a recording against the robot model it will be used with: cable count m and laser
// count k (a recording without laser columns fits any config), swivel columns only for cables
// with a swivel pulley. kFailedPrecondition with a message naming both counts on mismatch. (A
// different robot name is not an error: a nominal and a measured config of one robot may carry
// different names.)
Status check_against_model(const Recording& recording, const RobotModel& model);

// ---------------------------------------------------------------------------------------------
// Plausibility against the robot (every command that reads a recording or a pose list)
// ---------------------------------------------------------------------------------------------

// Bounds of what a recording of a cable robot in SI units can hold. The frame size is the diagonal
// of the box around the frame anchors (at least 1 mm), its centre the box's centre.
struct PlausibilityLimits {
  double position_frame_multiple = 10.0;  // commanded and reference positions: within this many
                                          // frame sizes of the frame centre, per axis
  double length_frame_multiple = 10.0;    // length_i and laser_j in (0, this many frame sizes]
  double max_abs_angle_rad = 6.283185307179586;  // roll, pitch, yaw
  double max_abs_tension_n = 1e6;                // tension_i
  double min_temperature_c = -100.0, max_temperature_c = 200.0;
  double max_noise_m = 1.0;        // noise_length_m, noise_laser_m, noise_reference_position_m
  double max_noise_force_n = 1e4;  // noise_force_n
  double max_noise_angle_rad = 3.141592653589793;  // noise_reference_angle_rad
  // Median |length_i| / nominal inverse-kinematics length at the commanded pose beyond this
  // factor, either way: the file is in another unit (mm, cm, km) whatever its `# units` says.
  double unit_ratio = 100.0;
};

// Checks every cell and noise statement of `recording` against `model` and `limits`, first the
// unit of the cable lengths as a whole ("<file>: length_1..length_8: looks like mm, expected m
// (median 710.2 vs 0.7128 m ...)"), then each cell in file order ("<file>:<line>: column <c>
// (cmd_x): 1e+300 m is outside the plausible range [-23.1, 23.6] m (10 frame sizes of 2.3 m
// around the frame centre)"). Numbers are printed with 6 significant digits. kInvalidArgument.
// Use after check_against_model (the counts must agree).
Status check_plausible(const Recording& recording, const RobotModel& model, std::string_view file,
                       const PlausibilityLimits& limits = {});
// The same for the poses of a pose list (positions and angles).
Status check_plausible(const PoseList& list, const RobotModel& model, std::string_view file,
                       const PlausibilityLimits& limits = {});

// ---------------------------------------------------------------------------------------------
// Recording <-> MeasurementSet (calibration/measurement.hpp)
// ---------------------------------------------------------------------------------------------

// The identification's view of a recording. Noise sigmas come from the metadata keys
// noise_length_m, noise_force_n, noise_laser_m, noise_reference_position_m and
// noise_reference_angle_rad when present (a value that is not a positive
// number is refused), else from `defaults`. A reference pose is taken when all six ref_* cells of
// a row are filled; a row with only some of them filled is refused (it names the pose). Tensions
// that are all empty in every row give empty tension vectors (no force sensors).
Result<MeasurementSet> to_measurement_set(const Recording& recording,
                                          const SensorNoise& defaults = {});

// The recording of a measurement set (poses numbered 0, 1, ...; the noise sigmas go to the
// metadata next to `metadata`'s entries). Refuses sets whose poses disagree on sizes. The
// swivel / inclinometer / IMU columns are written when some pose has such a reading.
Result<Recording> from_measurement_set(const MeasurementSet& set, Metadata metadata = {});

// ---------------------------------------------------------------------------------------------
// Pre-calibration experiments
// ---------------------------------------------------------------------------------------------

// One bench sample, as cdpr::ElongationSample (elongation.hpp): the cable loaded to tension_n
// has loaded length length_m (drum to platform anchor) and stretched by elongation_m.
struct CableSample {
  double length_m = 0.0;      // loaded length L, m
  double tension_n = 0.0;     // N
  double elongation_m = 0.0;  // measured elongation, m
};

struct CableExperiment {
  Metadata metadata;
  std::vector<CableSample> samples;
};

Result<CableExperiment> read_cable_experiment(const std::string& path);
Result<CableExperiment> parse_cable_experiment(std::string_view text, std::string_view name);
Status write_cable_experiment(const CableExperiment& experiment, const std::string& path);
Result<std::string> format_cable_experiment(const CableExperiment& experiment);

struct ForceSample {
  int channel = 1;       // cable / sensor number, 1..m
  double mass_kg = 0.0;  // the known hanging mass, kg (tension = mass * g)
  double raw = 0.0;      // sensor reading, raw units (raw = gain * tension + offset)
};

struct ForceSensorExperiment {
  Metadata metadata;  // may carry `gravity_m_s2` (default 9.81)
  std::vector<ForceSample> samples;
};

Result<ForceSensorExperiment> read_force_experiment(const std::string& path);
Result<ForceSensorExperiment> parse_force_experiment(std::string_view text, std::string_view name);
Status write_force_experiment(const ForceSensorExperiment& experiment, const std::string& path);
Result<std::string> format_force_experiment(const ForceSensorExperiment& experiment);

// ---------------------------------------------------------------------------------------------
// Pose lists (`cdpr-fit design-poses` writes them, `cdpr-fit simulate --poses` reads them)
// ---------------------------------------------------------------------------------------------

// Columns pose, x, y, z (m), roll, pitch, yaw (rad); pose indices strictly increasing.
struct PoseList {
  Metadata metadata;
  std::vector<Pose> poses;
  std::vector<int> lines;  // line of each pose in the file read (1-based); empty when not read
};

Result<PoseList> read_pose_list(const std::string& path);
Result<PoseList> parse_pose_list(std::string_view text, std::string_view name);
Status write_pose_list(const PoseList& list, const std::string& path);
Result<std::string> format_pose_list(const PoseList& list);

// ---------------------------------------------------------------------------------------------
// Helpers
// ---------------------------------------------------------------------------------------------

// 64-bit FNV-1a of a byte string, and "fnv1a64:<16 lower-case hex digits>" of a file's bytes.
std::uint64_t fnv1a64(std::string_view bytes);
Result<std::string> file_hash(const std::string& path);
// Shortest decimal that reads back to exactly `value` (std::to_chars); "" for NaN.
std::string format_number(double value);
// UTC now as "YYYY-MM-DDTHH:MM:SSZ".
std::string utc_timestamp();

}  // namespace cdpr::recording
