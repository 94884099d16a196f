#include "cdpr/config/robot_config.hpp"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>
#include <string>

#include "cdpr/calibration/kinematics.hpp"
#include "cdpr/calibration/model_check.hpp"
#include "testing/test_robots.hpp"

namespace cdpr::config {
namespace {

using ::testing::HasSubstr;
using ::testing::Not;

std::string source_path(const std::string& relative) {
  return std::string(CDPR_SOURCE_DIR) + "/" + relative;
}

std::string read_text(const std::string& path) {
  std::ifstream in(path);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

// Replaces the first occurrence of `from` (which must exist) in `text`.
std::string replace(std::string text, const std::string& from, const std::string& to) {
  const std::size_t at = text.find(from);
  EXPECT_NE(at, std::string::npos) << "test bug: '" << from << "' not in the text";
  if (at != std::string::npos) text.replace(at, from.size(), to);
  return text;
}

// 1-based line of the first occurrence of `needle`.
int line_of(const std::string& text, const std::string& needle) {
  const std::size_t at = text.find(needle);
  EXPECT_NE(at, std::string::npos) << "test bug: '" << needle << "' not in the text";
  int line = 1;
  for (std::size_t k = 0; k < at && k < text.size(); ++k) line += text[k] == '\n' ? 1 : 0;
  return line;
}

bool same_bits(double a, double b) {
  return std::memcmp(&a, &b, sizeof(double)) == 0;
}

template <typename Derived>
::testing::AssertionResult same_bits(const Eigen::MatrixBase<Derived>& a,
                                     const Eigen::MatrixBase<Derived>& b, const std::string& what) {
  if (a.rows() != b.rows() || a.cols() != b.cols()) {
    return ::testing::AssertionFailure() << what << ": sizes differ";
  }
  for (Eigen::Index r = 0; r < a.rows(); ++r) {
    for (Eigen::Index c = 0; c < a.cols(); ++c) {
      if (!same_bits(a(r, c), b(r, c))) {
        return ::testing::AssertionFailure()
               << what << "(" << r << "," << c << "): " << a(r, c) << " != " << b(r, c);
      }
    }
  }
  return ::testing::AssertionSuccess();
}

// Every field, bit for bit.
void expect_identical(const RobotModel& a, const RobotModel& b) {
  EXPECT_EQ(a.name, b.name);
  EXPECT_TRUE(same_bits(a.gravity, b.gravity));
  EXPECT_TRUE(same_bits(a.frame_anchors, b.frame_anchors, "frame_anchors"));
  EXPECT_TRUE(same_bits(a.platform_anchors, b.platform_anchors, "platform_anchors"));
  ASSERT_EQ(a.num_cables(), b.num_cables());
  for (std::size_t i = 0; i < static_cast<std::size_t>(a.num_cables()); ++i) {
    SCOPED_TRACE("cable " + std::to_string(i));
    EXPECT_TRUE(same_bits(a.pulleys[i].radius, b.pulleys[i].radius));
    EXPECT_TRUE(same_bits(a.pulleys[i].frame, b.pulleys[i].frame, "pulley frame"));
    const WinchModel &wa = a.winches[i], &wb = b.winches[i];
    EXPECT_TRUE(same_bits(wa.drum_diameter, wb.drum_diameter));
    EXPECT_TRUE(same_bits(wa.drum_pitch, wb.drum_pitch));
    EXPECT_TRUE(same_bits(wa.gear_ratio, wb.gear_ratio));
    EXPECT_TRUE(same_bits(wa.counts_per_rev, wb.counts_per_rev));
    EXPECT_TRUE(same_bits(wa.length_offset, wb.length_offset));
    EXPECT_EQ(wa.direction, wb.direction);
    const CableModel &ca = a.cables[i], &cb = b.cables[i];
    EXPECT_TRUE(same_bits(ca.ea, cb.ea));
    EXPECT_TRUE(same_bits(ca.mass_per_length, cb.mass_per_length));
    EXPECT_TRUE(same_bits(ca.routing_length, cb.routing_length));
    EXPECT_EQ(ca.elongation, cb.elongation);
    EXPECT_EQ(ca.polynomial.order, cb.polynomial.order);
    ASSERT_EQ(ca.polynomial.coefficients.size(), cb.polynomial.coefficients.size());
    for (std::size_t k = 0; k < ca.polynomial.coefficients.size(); ++k) {
      EXPECT_TRUE(same_bits(ca.polynomial.coefficients[k], cb.polynomial.coefficients[k]));
    }
    EXPECT_TRUE(same_bits(ca.polynomial.length_center, cb.polynomial.length_center));
    EXPECT_TRUE(same_bits(ca.polynomial.length_scale, cb.polynomial.length_scale));
    EXPECT_TRUE(same_bits(ca.polynomial.tension_center, cb.polynomial.tension_center));
    EXPECT_TRUE(same_bits(ca.polynomial.tension_scale, cb.polynomial.tension_scale));
    EXPECT_TRUE(same_bits(ca.f_min, cb.f_min));
    EXPECT_TRUE(same_bits(ca.f_max, cb.f_max));
    EXPECT_TRUE(same_bits(a.force_sensors[i].gain, b.force_sensors[i].gain));
    EXPECT_TRUE(same_bits(a.force_sensors[i].offset, b.force_sensors[i].offset));
  }
  EXPECT_TRUE(same_bits(a.platform.mass, b.platform.mass));
  EXPECT_TRUE(same_bits(a.platform.center_of_mass, b.platform.center_of_mass, "com"));
  EXPECT_TRUE(same_bits(a.platform.inertia, b.platform.inertia, "inertia"));
  EXPECT_TRUE(same_bits(a.home.position, b.home.position, "home.position"));
  EXPECT_TRUE(same_bits(a.home.rpy, b.home.rpy, "home.rpy"));
  ASSERT_EQ(a.lasers.size(), b.lasers.size());
  for (std::size_t j = 0; j < a.lasers.size(); ++j) {
    EXPECT_TRUE(same_bits(a.lasers[j].origin, b.lasers[j].origin, "laser origin"));
    EXPECT_TRUE(same_bits(a.lasers[j].direction, b.lasers[j].direction, "laser direction"));
    EXPECT_TRUE(same_bits(a.lasers[j].plane_point, b.lasers[j].plane_point, "plane point"));
    EXPECT_TRUE(same_bits(a.lasers[j].plane_normal, b.lasers[j].plane_normal, "plane normal"));
    EXPECT_TRUE(same_bits(a.lasers[j].range_min, b.lasers[j].range_min));
    EXPECT_TRUE(same_bits(a.lasers[j].range_max, b.lasers[j].range_max));
  }
}

const char* const kShipped[] = {"config/mini.yaml", "config/mini-measured.yaml",
                                "config/ipanema3.yaml"};

TEST(RobotConfig, EveryShippedConfigLoadsAndPassesTheModelCheck) {
  for (const char* file : kShipped) {
    SCOPED_TRACE(file);
    const Result<RobotModel> model = load_robot_config(source_path(file));
    ASSERT_TRUE(model.ok()) << model.status().to_string();
    EXPECT_TRUE(check_model(*model).ok()) << check_model(*model).to_string();
    EXPECT_EQ(model->num_cables(), 8);
    EXPECT_FALSE(model->lasers.empty());
  }
}

TEST(RobotConfig, MiniMatchesThePaperTableWithTheCable7Correction) {
  const Result<RobotModel> nominal = load_robot_config(source_path("config/mini.yaml"));
  const Result<RobotModel> measured = load_robot_config(source_path("config/mini-measured.yaml"));
  ASSERT_TRUE(nominal.ok()) << nominal.status().to_string();
  ASSERT_TRUE(measured.ok()) << measured.status().to_string();
  // Table 1, SolidWorks column, cable 1 and the corrected cable 7 (mm -> m).
  EXPECT_EQ(nominal->frame_anchors.col(0), Eigen::Vector3d(0.5, -0.378, -0.4415));
  EXPECT_EQ(nominal->frame_anchors.col(6), Eigen::Vector3d(-0.5315, 0.345, 0.4415));
  EXPECT_EQ(measured->frame_anchors.col(6), Eigen::Vector3d(-0.52415, 0.3479, 0.42968));
  // Each cable in its own corner: signs of x and y differ between any two cables on one level.
  for (const RobotModel* m : {&*nominal, &*measured}) {
    for (int i = 0; i < 8; ++i) {
      for (int j = i + 1; j < 8; ++j) {
        const Eigen::Vector3d a = m->frame_anchors.col(i), b = m->frame_anchors.col(j);
        const bool same_corner =
            (a.x() > 0) == (b.x() > 0) && (a.y() > 0) == (b.y() > 0) && (a.z() > 0) == (b.z() > 0);
        EXPECT_FALSE(same_corner) << m->name << ": cables " << i + 1 << " and " << j + 1;
      }
    }
  }
  // Measured and nominal differ by millimetres, not by a corner.
  const double worst =
      (measured->frame_anchors - nominal->frame_anchors).colwise().norm().maxCoeff();
  EXPECT_GT(worst, 0.001);
  EXPECT_LT(worst, 0.02);
  // The defaults block reached every cable; the pulley frames are orthonormal and point their
  // reference direction towards the frame centre (horizontal).
  for (std::size_t i = 0; i < 8; ++i) {
    EXPECT_EQ(nominal->pulleys[i].radius, 0.025);
    EXPECT_EQ(nominal->force_sensors[i].gain, 2.0);
    EXPECT_EQ(nominal->winches[i].counts_per_rev, 65536.0);
    const Eigen::Vector3d ex = nominal->pulleys[i].frame.col(0);
    EXPECT_NEAR(ex.z(), 0.0, 1e-15);
    EXPECT_LT(ex.head<2>().dot(nominal->frame_anchors.col(static_cast<int>(i)).head<2>()), 0.0);
  }
}

// config/mini.yaml and the tests' MINI (calibration/testing/test_robots.hpp) are the same robot.
TEST(RobotConfig, MiniIsTheTestRobot) {
  const Result<RobotModel> file = load_robot_config(source_path("config/mini.yaml"));
  ASSERT_TRUE(file.ok()) << file.status().to_string();
  const RobotModel code = cdpr::testing::mini_robot();
  EXPECT_TRUE(same_bits(file->frame_anchors, code.frame_anchors, "frame_anchors"));
  EXPECT_TRUE(same_bits(file->platform_anchors, code.platform_anchors, "platform_anchors"));
  for (std::size_t i = 0; i < 8; ++i) {
    SCOPED_TRACE("cable " + std::to_string(i + 1));
    EXPECT_EQ(file->pulleys[i].radius, code.pulleys[i].radius);
    EXPECT_TRUE(same_bits(file->pulleys[i].frame, code.pulleys[i].frame, "pulley frame"));
    EXPECT_EQ(file->winches[i].drum_diameter, code.winches[i].drum_diameter);
    EXPECT_EQ(file->winches[i].drum_pitch, code.winches[i].drum_pitch);
    EXPECT_EQ(file->winches[i].gear_ratio, code.winches[i].gear_ratio);
    EXPECT_EQ(file->winches[i].counts_per_rev, code.winches[i].counts_per_rev);
    EXPECT_EQ(file->winches[i].direction, code.winches[i].direction);
    EXPECT_EQ(file->cables[i].ea, code.cables[i].ea);
    EXPECT_EQ(file->cables[i].mass_per_length, code.cables[i].mass_per_length);
    EXPECT_EQ(file->cables[i].routing_length, code.cables[i].routing_length);
    EXPECT_EQ(file->cables[i].elongation, code.cables[i].elongation);
    EXPECT_EQ(file->cables[i].f_min, code.cables[i].f_min);
    EXPECT_EQ(file->cables[i].f_max, code.cables[i].f_max);
    EXPECT_EQ(file->force_sensors[i].gain, code.force_sensors[i].gain);
    EXPECT_EQ(file->force_sensors[i].offset, code.force_sensors[i].offset);
  }
  EXPECT_EQ(file->platform.mass, code.platform.mass);
  EXPECT_EQ(file->platform.center_of_mass, code.platform.center_of_mass);
  EXPECT_EQ(file->home.position, code.home.position);
  EXPECT_EQ(file->home.rpy, code.home.rpy);
}

// Issue 18: the shipped 4-cable suspended crane loads, passes the model check for a suspended
// robot (equilibrium at home) and is the tests' crane (calibration/testing/test_robots.hpp).
TEST(RobotConfig, Crane4IsASuspendedFourCableRobotAndTheTestCrane) {
  const Result<RobotModel> file = load_robot_config(source_path("config/crane4.yaml"));
  ASSERT_TRUE(file.ok()) << file.status().to_string();
  EXPECT_TRUE(file->suspended);
  EXPECT_EQ(file->num_cables(), 4);
  EXPECT_TRUE(file->lasers.empty());
  EXPECT_TRUE(check_model(*file).ok()) << check_model(*file).to_string();
  const RobotModel code = cdpr::testing::crane_robot();
  EXPECT_TRUE(same_bits(file->frame_anchors, code.frame_anchors, "frame_anchors"));
  EXPECT_TRUE(same_bits(file->platform_anchors, code.platform_anchors, "platform_anchors"));
  for (std::size_t i = 0; i < 4; ++i) {
    SCOPED_TRACE("cable " + std::to_string(i + 1));
    EXPECT_EQ(file->pulleys[i].radius, code.pulleys[i].radius);
    EXPECT_TRUE(same_bits(file->pulleys[i].frame, code.pulleys[i].frame, "pulley frame"));
    EXPECT_EQ(file->winches[i].drum_diameter, code.winches[i].drum_diameter);
    EXPECT_EQ(file->cables[i].ea, code.cables[i].ea);
    EXPECT_EQ(file->cables[i].routing_length, code.cables[i].routing_length);
    EXPECT_EQ(file->cables[i].f_max, code.cables[i].f_max);
    EXPECT_EQ(file->force_sensors[i].gain, code.force_sensors[i].gain);
  }
  EXPECT_EQ(file->platform.mass, code.platform.mass);
  EXPECT_EQ(file->platform.center_of_mass, code.platform.center_of_mass);
  EXPECT_EQ(file->home.position, code.home.position);
  // Saved and read back, it stays suspended.
  const Result<RobotModel> again = parse_robot_config(save_robot_config(*file), "saved.yaml");
  ASSERT_TRUE(again.ok()) << again.status().to_string();
  EXPECT_TRUE(again->suspended);
  EXPECT_THAT(save_robot_config(*file), HasSubstr("suspended: true"));
  EXPECT_THAT(save_robot_config(cdpr::testing::mini_robot()), Not(HasSubstr("suspended")));
}

TEST(RobotConfig, LaserSeesTheFloorAtHomeWithinItsRange) {
  for (const char* file : kShipped) {
    SCOPED_TRACE(file);
    const Result<RobotModel> model = load_robot_config(source_path(file));
    ASSERT_TRUE(model.ok()) << model.status().to_string();
    const LaserModel& laser = model->lasers[0];
    const Eigen::Matrix3d R = rotation_from_rpy<double>(model->home.rpy);
    const Eigen::Vector3d origin = model->home.position + R * laser.origin;
    const Eigen::Vector3d beam = R * laser.direction;
    const double t =
        (laser.plane_point - origin).dot(laser.plane_normal) / beam.dot(laser.plane_normal);
    EXPECT_GT(t, laser.range_min);
    EXPECT_LT(t, laser.range_max);
  }
}

// Saving, loading the text again and saving once more gives the same model and the same text.
void expect_save_load_exact(const RobotModel& model) {
  const std::string saved = save_robot_config(model);
  const Result<RobotModel> again = parse_robot_config(saved, "saved.yaml");
  ASSERT_TRUE(again.ok()) << again.status().to_string() << "\n" << saved;
  expect_identical(model, *again);
  EXPECT_EQ(save_robot_config(*again), saved);
}

TEST(RobotConfig, SaveThenLoadIsExact) {
  for (const char* file : kShipped) {
    SCOPED_TRACE(file);
    const Result<RobotModel> model = load_robot_config(source_path(file));
    ASSERT_TRUE(model.ok()) << model.status().to_string();
    expect_save_load_exact(*model);
  }
}

TEST(RobotConfig, WrittenFileCarriesTheHeaderAndLoadsBackExactly) {
  const Result<RobotModel> model = load_robot_config(source_path("config/mini.yaml"));
  ASSERT_TRUE(model.ok()) << model.status().to_string();
  const std::string path = ::testing::TempDir() + "robot_config_test_written.yaml";
  const std::string header = "# geometry version 3\n";
  ASSERT_TRUE(write_robot_config(path, *model, header).ok());
  const std::string text = read_text(path);
  EXPECT_EQ(text, header + save_robot_config(*model));
  const Result<RobotModel> again = load_robot_config(path);
  ASSERT_TRUE(again.ok()) << again.status().to_string();
  expect_identical(*model, *again);
  std::remove(path.c_str());
  const Status bad = write_robot_config("/nonexistent/dir/robot.yaml", *model);
  EXPECT_EQ(bad.code(), ErrorCode::kNotFound);
  EXPECT_THAT(std::string(bad.message()), HasSubstr("/nonexistent/dir/robot.yaml"));
}

// Found by fuzz/robot_config (input kept in fuzz/regressions/robot_config/): a pulley axis that is
// not a unit vector with a reference that is not perpendicular to it loaded into a frame whose
// saved reference moved by an ulp at every further load and save.
TEST(RobotConfig, SaveThenLoadIsExactForAPulleyGivenWithATiltedAxisAndAnObliqueReference) {
  std::string text = read_text(source_path("config/mini.yaml"));
  const std::string given = "pulley: {axis: [0, 0, 1], reference: [-0.5, -0.378, 0]}";
  const std::size_t at = text.find(given);
  ASSERT_NE(at, std::string::npos);
  text.replace(at, given.size(), "pulley: {axis: [4, 0, 1], reference: [-0.5, -0.378, 0]}");
  const Result<RobotModel> model = parse_robot_config(text, "tilted.yaml");
  ASSERT_TRUE(model.ok()) << model.status().to_string();
  expect_save_load_exact(*model);
}

// A negative zero (a file may say "-0.") is written as 0: "-0" would read back as the integer 0
// and a second save would differ from the first (found by fuzz/robot_config_fuzz.cc).
TEST(RobotConfig, SaveWritesANegativeZeroAsZeroSoThatSaveAndLoadAreStable) {
  Result<RobotModel> model = load_robot_config(source_path("config/mini.yaml"));
  ASSERT_TRUE(model.ok()) << model.status().to_string();
  model->platform_anchors(0, 6) = -0.0;
  const std::string saved = save_robot_config(*model);
  EXPECT_EQ(saved.find("-0,"), std::string::npos) << saved;
  auto again = parse_robot_config(saved, "saved.yaml");
  ASSERT_TRUE(again.ok()) << again.status().to_string();
  EXPECT_EQ(save_robot_config(*again), saved);
}

TEST(RobotConfig, SaveKeepsNumbersThatNeedAllSeventeenDigits) {
  Result<RobotModel> model = load_robot_config(source_path("config/mini.yaml"));
  ASSERT_TRUE(model.ok()) << model.status().to_string();
  // Values a %.15g writer would corrupt, and per-cable differences from the defaults.
  model->frame_anchors(0, 3) = 0.1 + 0.2;  // 0.30000000000000004
  model->platform_anchors(2, 5) = std::nextafter(0.05, 1.0);
  model->cables[2].ea = 19999.999999999996;
  model->winches[4].direction = -1;
  model->winches[5].length_offset = -1.0 / 3.0;
  model->force_sensors[6].offset = 1e-300;
  model->pulleys[7].radius = 0.0;
  model->cables[1].elongation = ElongationKind::kPolynomial;
  model->cables[1].polynomial.order = 2;
  model->cables[1].polynomial.coefficients = {1e-4, 2.0 / 3.0 * 1e-5, -7e-6, 1e-7, 3e-8, -1e-9};
  model->cables[1].polynomial.length_center = 1.4;
  model->cables[1].polynomial.tension_scale = 150.0;
  model->platform.inertia(0, 1) = model->platform.inertia(1, 0) = 1e-5;
  model->home.rpy = Eigen::Vector3d(0.01, -0.02, 1.0 / 7.0);
  ASSERT_TRUE(check_model(*model).ok()) << check_model(*model).to_string();
  const std::string saved = save_robot_config(*model);
  const Result<RobotModel> again = parse_robot_config(saved, "saved.yaml");
  ASSERT_TRUE(again.ok()) << again.status().to_string() << "\n" << saved;
  expect_identical(*model, *again);
}

TEST(RobotConfig, MissingFileIsNotFound) {
  const Result<RobotModel> model = load_robot_config("/nonexistent/robot.yaml");
  ASSERT_FALSE(model.ok());
  EXPECT_EQ(model.status().code(), ErrorCode::kNotFound);
  EXPECT_THAT(std::string(model.status().message()), HasSubstr("/nonexistent/robot.yaml"));
}

// A bad config is refused with "file:line: field: what".
struct BadConfig {
  const char* name;
  std::string from;       // text in config/mini.yaml ...
  std::string to;         // ... replaced by this
  std::string line_text;  // the error must point at the line holding this text (after replace)
  std::string field;      // and name this field
  std::string what;       // and say this
};

class RobotConfigRefuses : public ::testing::TestWithParam<BadConfig> {};

TEST_P(RobotConfigRefuses, WithFileLineAndField) {
  const BadConfig& bad = GetParam();
  const std::string text = replace(read_text(source_path("config/mini.yaml")), bad.from, bad.to);
  const Result<RobotModel> model = parse_robot_config(text, "config/mini.yaml");
  ASSERT_FALSE(model.ok()) << "accepted:\n" << text;
  const std::string message(model.status().message());
  const std::string where =
      "config/mini.yaml:" + std::to_string(line_of(text, bad.line_text)) + ":";
  EXPECT_THAT(message, HasSubstr(where)) << message;
  EXPECT_THAT(message, HasSubstr(bad.field + ":")) << message;
  EXPECT_THAT(message, HasSubstr(bad.what)) << message;
}

INSTANTIATE_TEST_SUITE_P(
    BadFields, RobotConfigRefuses,
    ::testing::Values(
        BadConfig{"NegativeEa", "  ea: 20000", "  ea: -5", "ea: -5", "defaults.ea",
                  "expected a positive number (N), got -5"},
        BadConfig{"NegativeEaOnOneCable", "platform_anchor: [-0.06, 0.075, -0.03]",
                  "platform_anchor: [-0.06, 0.075, -0.03]\n    ea: -5", "ea: -5", "cables[2].ea",
                  "expected a positive number (N), got -5"},
        BadConfig{"ShortVector", "[0.5, 0.378, -0.4415]", "[0.5, 0.378]", "[0.5, 0.378]",
                  "cables[3].frame_anchor", "expected a list of 3 numbers (m), got a list of 2"},
        BadConfig{"NaN", "[0.06, -0.075, 0.03]", "[0.06, .nan, 0.05]", ".nan",
                  "cables[4].platform_anchor[1]", "expected a finite number (m), got .nan"},
        BadConfig{"NotANumber", "mass: 2.0", "mass: heavy", "mass: heavy", "platform.mass",
                  "expected a positive number (kg), got heavy"},
        BadConfig{"MissingField", "    platform_anchor: [0.06, 0.075, 0.03]\n", "",
                  "[0.5315, 0.345, 0.4415]", "cables[7].platform_anchor", "missing (b_i"},
        BadConfig{"MissingDefaultedField", "  f_max: 200               # N\n", "",
                  "[0.5, -0.378, -0.4415]", "cables[0].f_max",
                  "missing (maximum tension in N); give it here or in defaults"},
        BadConfig{"UnknownField", "drum_pitch: 0.002", "drum_pich: 0.002", "drum_pich",
                  "defaults.winch.drum_pich", "unknown field (known fields: drum_diameter"},
        BadConfig{"DirectionNotUnitSign", "direction: 1,", "direction: 2,", "direction: 2",
                  "defaults.winch.direction", "expected 1 or -1, got 2"},
        BadConfig{"TensionLimitsReversed", "  f_min: 5 ", "  f_min: 500 ", "f_min: 500",
                  "cables[0].f_min", "above the maximum"},
        BadConfig{"ZeroLaserDirection", "direction: [0, 0, -1]", "direction: [0, 0, 0]",
                  "direction: [0, 0, 0]", "lasers[0].direction", "expected a unit vector"},
        BadConfig{"NonUnitLaserDirection", "direction: [0, 0, -1]", "direction: [0, 0, -2]",
                  "direction: [0, 0, -2]", "lasers[0].direction", "expected a unit vector"},
        BadConfig{"PulleyReferenceAlongAxis", "{axis: [0, 0, -1], reference: [-0.5315, 0.345, 0]}",
                  "{axis: [0, 0, -1], reference: [0, 0, 2]}", "reference: [0, 0, 2]",
                  "cables[4].pulley.reference", "not parallel to the pulley axis"},
        BadConfig{"PolynomialWithTooFewCoefficients", "elongation: hooke",
                  "elongation: {model: polynomial, order: 2, coefficients: [1, 2, 3]}",
                  "model: polynomial", "defaults.elongation.coefficients",
                  "order 2 needs a list of 6 numbers, got a list of 3"},
        BadConfig{"UnknownTopLevelField", "name: MINI\n", "name: MINI\nlaser: []\n", "laser: []",
                  "laser", "unknown field (known fields: name, gravity"},
        BadConfig{"RepeatedField", "    platform_anchor: [0.06, 0.075, 0.03]\n",
                  "    platform_anchor: [0.06, 0.075, 0.03]\n    ea: 1\n    ea: 2\n", "    ea: 2\n",
                  "cables[7].ea", "field given twice"},
        BadConfig{"ZeroDrumDiameter", "drum_diameter: 0.04", "drum_diameter: 0", "drum_diameter: 0",
                  "defaults.winch.drum_diameter", "expected a positive number (m), got 0"}),
    [](const ::testing::TestParamInfo<BadConfig>& param_info) {
      return std::string(param_info.param.name);
    });

// All platform anchors at the origin: the cables cannot exert a moment, rank 3 < 6.
TEST(RobotConfig, RefusesASingularStructureMatrixAtHome) {
  std::string text = read_text(source_path("config/mini.yaml"));
  for (const char* corner :
       {"[0.06, -0.075, -0.03]", "[-0.06, -0.075, -0.03]", "[-0.06, 0.075, -0.03]",
        "[0.06, 0.075, -0.03]", "[0.06, -0.075, 0.03]", "[-0.06, -0.075, 0.03]",
        "[-0.06, 0.075, 0.03]", "[0.06, 0.075, 0.03]"}) {
    text = replace(text, std::string("platform_anchor: ") + corner, "platform_anchor: [0, 0, 0]");
  }
  const Result<RobotModel> model = parse_robot_config(text, "config/mini.yaml");
  ASSERT_FALSE(model.ok());
  const std::string message(model.status().message());
  EXPECT_THAT(message,
              HasSubstr("config/mini.yaml:" + std::to_string(line_of(text, "\ncables:") + 1) +
                        ": cables: the structure matrix at the home pose has rank 3 < 6"))
      << message;
}

// All frame anchors in one point: rank < 6 as well.
TEST(RobotConfig, RefusesCoincidentFrameAnchors) {
  std::string text = read_text(source_path("config/mini.yaml"));
  for (const char* a :
       {"[0.5, -0.378, -0.4415]", "[-0.5, -0.378, -0.4415]", "[-0.5, 0.378, -0.4415]",
        "[0.5, 0.378, -0.4415]", "[0.5315, -0.345, 0.4415]", "[-0.5315, -0.345, 0.4415]",
        "[-0.5315, 0.345, 0.4415]", "[0.5315, 0.345, 0.4415]"}) {
    text = replace(text, std::string("frame_anchor: ") + a, "frame_anchor: [0, 0, 1]");
  }
  const Result<RobotModel> model = parse_robot_config(text, "config/mini.yaml");
  ASSERT_FALSE(model.ok());
  EXPECT_EQ(model.status().code(), ErrorCode::kInvalidArgument);
  EXPECT_THAT(std::string(model.status().message()), HasSubstr("cables: the structure matrix"));
}

TEST(RobotConfig, YamlSyntaxErrorIsAParseErrorWithTheLine) {
  const std::string text =
      replace(read_text(source_path("config/mini.yaml")), "  ea: 20000", "  ea: [20000");
  const Result<RobotModel> model = parse_robot_config(text, "config/mini.yaml");
  ASSERT_FALSE(model.ok());
  EXPECT_EQ(model.status().code(), ErrorCode::kParseError);
  EXPECT_THAT(std::string(model.status().message()), HasSubstr("config/mini.yaml:"));
}

TEST(RobotConfig, PerCableOverridesWinOverDefaults) {
  std::string text = read_text(source_path("config/mini.yaml"));
  text = replace(text, "platform_anchor: [-0.06, -0.075, 0.03]",
                 "platform_anchor: [-0.06, -0.075, 0.03]\n    winch: {direction: -1}\n"
                 "    force_sensor: {offset: 0.5}\n    ea: 30000");
  text =
      replace(text, "pulley: {axis: [0, 0, -1], reference: [-0.5315, -0.345, 0]}", "pulley: none");
  const Result<RobotModel> model = parse_robot_config(text, "config/mini.yaml");
  ASSERT_TRUE(model.ok()) << model.status().to_string();
  EXPECT_EQ(model->winches[5].direction, -1);
  EXPECT_EQ(model->winches[5].drum_diameter, 0.04);  // the rest of the group still defaulted
  EXPECT_EQ(model->force_sensors[5].offset, 0.5);
  EXPECT_EQ(model->force_sensors[5].gain, 2.0);
  EXPECT_EQ(model->cables[5].ea, 30000.0);
  EXPECT_EQ(model->cables[4].ea, 20000.0);
  EXPECT_EQ(model->pulleys[7].radius, 0.0);
  EXPECT_EQ(model->pulleys[6].radius, 0.025);
  EXPECT_EQ(model->pulleys[7].frame, Eigen::Matrix3d::Identity());
}

// Issue 18: swivel encoders (per cable, with defaults) and the inclinometer / IMU mounting.
TEST(RobotConfig, SwivelEncodersAndInclinometerLoadAndSaveExactly) {
  std::string text = read_text(source_path("config/mini.yaml"));
  text = replace(text, "  force_sensor: {gain: 2, offset: 0}\n",
                 "  force_sensor: {gain: 2, offset: 0}\n  swivel_encoder: {zero: 0.1}\n");
  text = replace(text, "platform_anchor: [-0.06, -0.075, 0.03]",
                 "platform_anchor: [-0.06, -0.075, 0.03]\n    swivel_encoder: {direction: -1}");
  text += "inclinometer: {mounting_rpy: [0.01, -0.02, 1.5], yaw_zero: 0.25}\n";
  const Result<RobotModel> model = parse_robot_config(text, "config/mini.yaml");
  ASSERT_TRUE(model.ok()) << model.status().to_string();
  ASSERT_EQ(model->swivel_encoders.size(), 8u);
  EXPECT_EQ(model->swivel_encoder(0).zero, 0.1);
  EXPECT_EQ(model->swivel_encoder(0).direction, 1);
  EXPECT_EQ(model->swivel_encoder(5).zero, 0.1);  // the rest of the group still defaulted
  EXPECT_EQ(model->swivel_encoder(5).direction, -1);
  EXPECT_EQ(model->inclinometer.mounting_rpy, Eigen::Vector3d(0.01, -0.02, 1.5));
  EXPECT_EQ(model->inclinometer.yaw_zero, 0.25);
  const std::string saved = save_robot_config(*model);
  EXPECT_THAT(saved, HasSubstr("swivel_encoder: {zero: 0.1, direction: -1}"));
  EXPECT_THAT(saved, HasSubstr("inclinometer: {mounting_rpy: [0.01, -0.02, 1.5], yaw_zero: 0.25}"));
  const Result<RobotModel> again = parse_robot_config(saved, "saved.yaml");
  ASSERT_TRUE(again.ok()) << again.status().to_string() << "\n" << saved;
  EXPECT_EQ(save_robot_config(*again), saved);
  for (int i = 0; i < 8; ++i) {
    EXPECT_EQ(again->swivel_encoder(i).zero, model->swivel_encoder(i).zero);
    EXPECT_EQ(again->swivel_encoder(i).direction, model->swivel_encoder(i).direction);
  }
  EXPECT_EQ(again->inclinometer.mounting_rpy, model->inclinometer.mounting_rpy);
  // Without them a config saves as before: no swivel_encoder or inclinometer key.
  const Result<RobotModel> plain = load_robot_config(source_path("config/mini.yaml"));
  ASSERT_TRUE(plain.ok());
  EXPECT_THAT(save_robot_config(*plain), Not(HasSubstr("swivel_encoder")));
  EXPECT_THAT(save_robot_config(*plain), Not(HasSubstr("inclinometer")));
  // A direction other than +-1 is refused with the line and field.
  const std::string bad =
      replace(text, "swivel_encoder: {direction: -1}", "swivel_encoder: {direction: 2}");
  const Result<RobotModel> refused = parse_robot_config(bad, "config/mini.yaml");
  ASSERT_FALSE(refused.ok());
  EXPECT_THAT(std::string(refused.status().message()),
              HasSubstr("cables[5].swivel_encoder.direction"));
}

}  // namespace
}  // namespace cdpr::config
