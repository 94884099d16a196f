// cdprd --check-config (config_check.hpp): every file before the bus, each error named by file,
// line and field; and cdprd itself checks them before it opens the bus.
#include "cdpr/controller/config_check.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "cdpr/config/robot_config.hpp"
#include "subprocess.hpp"

namespace cdpr::controller {
namespace {

namespace fs = std::filesystem;
const std::string kSrc = CDPR_SOURCE_DIR;

std::string read(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::string replaced(std::string text, const std::string& from, const std::string& to) {
  const auto at = text.find(from);
  EXPECT_NE(at, std::string::npos) << from;
  if (at != std::string::npos) text.replace(at, from.size(), to);
  return text;
}

// mini.yaml with every anchor coordinate x 1000: a robot file written in millimetres.
std::string mini_in_millimetres() {
  const std::string text = read(kSrc + "/config/mini.yaml");
  const std::regex anchor(R"(((?:frame|platform)_anchor: )\[([^\]]*)\])");
  std::string out;
  auto last = text.cbegin();
  for (std::sregex_iterator it(text.begin(), text.end(), anchor), end; it != end; ++it) {
    out.append(last, (*it)[0].first);
    std::string values;
    std::stringstream in((*it)[2].str());
    for (std::string v; std::getline(in, v, ',');) {
      values += (values.empty() ? "" : ", ") + std::to_string(1000.0 * std::stod(v));
    }
    out += (*it)[1].str() + "[" + values + "]";
    last = (*it)[0].second;
  }
  out.append(last, text.cend());
  return out;
}

class ConfigCheck : public ::testing::Test {
 protected:
  void SetUp() override {
    char tmpl[] = "/tmp/cdpr-config-check-XXXXXX";
    ASSERT_NE(::mkdtemp(tmpl), nullptr);
    dir_ = tmpl;
    // The virtual robot's network with its EDS files found from here.
    write("net.yaml", replaced(replaced(read(kSrc + "/config/sim/canopen.yaml"), "../eds/",
                                        kSrc + "/config/eds/"),
                               "../eds/", kSrc + "/config/eds/"));
    write("robot.yaml", read(kSrc + "/config/mini.yaml"));
    daemon_ = "robot: robot.yaml\ncanopen: net.yaml\nlaser: " + kSrc +
              "/config/sim/laser.yaml\nstate_directory: state\nrealtime: {priority: 0}\n"
              "control: {socket: " +
              dir_ + "/cdprd.sock}\n";
    write("cdprd.yaml", daemon_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  void write(const std::string& name, const std::string& text) {
    std::ofstream(dir_ + "/" + name) << text;
  }
  std::string path(const std::string& name) const { return dir_ + "/" + name; }
  // Every error of the checks, one per line.
  std::string errors() const {
    std::string out;
    for (const Status& s : check_daemon_files(path("cdprd.yaml"))) out += s.to_string() + "\n";
    return out;
  }
  // The line of `needle` in a written file (1-based).
  int line_of(const std::string& name, const std::string& needle) const {
    std::ifstream in(path(name));
    int n = 0;
    for (std::string l; std::getline(in, l);) {
      ++n;
      if (l.find(needle) != std::string::npos) return n;
    }
    return 0;
  }

  std::string dir_, daemon_;
};

TEST_F(ConfigCheck, AValidConfigurationHasNoError) {
  EXPECT_EQ(errors(), "");
}

TEST_F(ConfigCheck, TheShippedHandRunConfigurationIsValid) {
  for (const Status& s : check_daemon_files(kSrc + "/config/sim/cdprd.yaml")) {
    ADD_FAILURE() << s.to_string();
  }
}

TEST(RobotPlausibility, EveryShippedRobotFileIsPlausible) {
  for (const char* name : {"mini.yaml", "mini-measured.yaml", "crane4.yaml", "ipanema3.yaml"}) {
    auto r = config::check_robot_config(kSrc + "/config/" + name);
    ASSERT_TRUE(r.ok()) << r.status().to_string();
    for (const Status& s : r->findings) ADD_FAILURE() << s.to_string();
  }
}

TEST_F(ConfigCheck, ARobotFileInMillimetresIsRefusedAndSaysSo) {
  write("robot.yaml", mini_in_millimetres());
  const std::string e = errors();
  EXPECT_NE(e.find(path("robot.yaml") + ":"), std::string::npos) << e;
  EXPECT_NE(e.find(".frame_anchor: the frame anchors span"), std::string::npos) << e;
  EXPECT_NE(e.find("(looks like mm, expected m)"), std::string::npos) << e;
}

TEST_F(ConfigCheck, CountsPerMetreThatDisagreeWithTheRobotFileAreNamedAtTheirLine) {
  write("net.yaml", replaced(read(path("net.yaml")), "counts_per_unit: 5214528.789",
                             "counts_per_unit: 1000000"));
  const std::string e = errors();
  const std::string at = path("net.yaml") + ":" +
                         std::to_string(line_of("net.yaml", "counts_per_unit")) +
                         ": profiles.winch.counts_per_unit: 1000000 counts per metre, but ";
  EXPECT_NE(e.find(at), std::string::npos) << e;
  // One error for the profile's eight drives, with the value to write.
  EXPECT_NE(e.find(" gives 5214528.79 for cable 1, 2, 3, 4, 5, 6, 7, 8 (winch: "),
            std::string::npos)
      << e;
  EXPECT_NE(e.find("write 5214528.789"), std::string::npos) << e;
  EXPECT_EQ(e.find("counts per metre", e.find("counts per metre") + 1), std::string::npos) << e;
}

TEST_F(ConfigCheck, ForceGainsThatDisagreeWithTheRobotFileAreNamedAtTheirLine) {
  write("net.yaml", replaced(read(path("net.yaml")), "gain: 2", "gain: 2.5"));
  const std::string e = errors();
  const std::string at = path("net.yaml") + ":" + std::to_string(line_of("net.yaml", "gain:")) +
                         ": profiles.force.gain: gain 2.5, but " + path("robot.yaml") +
                         " has force_sensor.gain 2 for cable 1, 2, 3, 4, 5, 6, 7, 8";
  EXPECT_NE(e.find(at), std::string::npos) << e;
}

TEST_F(ConfigCheck, AOneMicrosecondSyncPeriodIsRefusedWithTheRange) {
  write("cdprd.yaml", replaced(daemon_, "realtime: {priority: 0}",
                               "realtime: {priority: 0, sync_period_ms: 0.001}"));
  const std::string e = errors();
  EXPECT_NE(e.find(path("cdprd.yaml") + ":5:"), std::string::npos) << e;
  EXPECT_NE(e.find("realtime.sync_period_ms: must be 0 (the network's) or within [1, 1000] ms"),
            std::string::npos)
      << e;
  // The network's own period.
  write("cdprd.yaml", daemon_);
  write("net.yaml",
        replaced(read(path("net.yaml")), "sync_period_ms: 20", "sync_period_ms: 0.001"));
  const std::string n = errors();
  EXPECT_NE(n.find(path("net.yaml") + ":" + std::to_string(line_of("net.yaml", "sync_period_ms")) +
                   ": master.sync_period_ms: expected a number within 1..1000"),
            std::string::npos)
      << n;
}

TEST_F(ConfigCheck, ASyncPeriodTheBusCannotCarryIsRefusedWithTheLoad) {
  write("net.yaml", replaced(read(path("net.yaml")), "sync_period_ms: 20", "sync_period_ms: 1"));
  const std::string e = errors();
  EXPECT_NE(e.find(path("net.yaml") + ": master.sync_period_ms: a SYNC period of 1 ms carries"),
            std::string::npos)
      << e;
  EXPECT_NE(e.find("% of the bus at 1000000 bit/s"), std::string::npos) << e;
}

TEST_F(ConfigCheck, ASocketDirectoryThatCannotBeMadeIsNamed) {
  // A missing directory is made at start (its parent is writable); one under a file cannot be.
  write("cdprd.yaml", replaced(daemon_, "/cdprd.sock", "/new-dir/cdprd.sock"));
  EXPECT_EQ(errors(), "");
  write("a-file", "");
  write("cdprd.yaml", replaced(daemon_, "/cdprd.sock", "/a-file/run/cdprd.sock"));
  const std::string e = errors();
  EXPECT_NE(e.find(path("cdprd.yaml") + ": control.socket: the directory '" + dir_ +
                   "/a-file/run' cannot be made: '" + dir_ + "/a-file' is not a directory"),
            std::string::npos)
      << e;
}

TEST_F(ConfigCheck, AnUnknownControlGroupIsNamed) {
  write("cdprd.yaml", replaced(daemon_, "cdprd.sock}", "cdprd.sock, group: no-such-group-cdpr}"));
  const std::string e = errors();
  EXPECT_NE(e.find(path("cdprd.yaml") + ": control.group: no group 'no-such-group-cdpr'"),
            std::string::npos)
      << e;
}

TEST_F(ConfigCheck, AStartUpWriteOfTheWrongSizeIsNamedAgainstTheEds) {
  write("net.yaml", replaced(read(path("net.yaml")), "    profile_velocity: 20000\n",
                             "    profile_velocity: 20000\n    sdo:\n"
                             "      - {object: \"0x6083:00\", type: u16, value: 100}\n"));
  const std::string e = errors();
  EXPECT_NE(e.find(path("net.yaml") + ":" + std::to_string(line_of("net.yaml", "0x6083:00")) +
                   ": profiles.winch.sdo[0]: node 1 (winch1): the master writes 0x6083:00 "
                   "(sdo write) as u16, but "),
            std::string::npos)
      << e;
  EXPECT_NE(e.find("is UNSIGNED32"), std::string::npos) << e;
}

TEST_F(ConfigCheck, TensionMarginsWiderThanTheTensionRangeAreNamed) {
  write("cdprd.yaml", daemon_ + "motion: {tension_margin: 100}\n");
  const std::string e = errors();
  EXPECT_NE(e.find(path("cdprd.yaml") +
                   ": motion.tension_margin: 100 N on both sides leaves nothing of cable 1's "
                   "[5, 200] N"),
            std::string::npos)
      << e;
}

TEST_F(ConfigCheck, EveryErrorIsReportedNotOnlyTheFirst) {
  write("robot.yaml", mini_in_millimetres());
  write("cdprd.yaml", replaced(daemon_, "cdprd.sock}", "cdprd.sock, group: no-such-group-cdpr}"));
  const std::string e = errors();
  EXPECT_NE(e.find("looks like mm"), std::string::npos) << e;
  EXPECT_NE(e.find("no group 'no-such-group-cdpr'"), std::string::npos) << e;
}

// --- the cdprd process -------------------------------------------------------------------------

struct Exit {
  int status = -1;
  std::string output;
};

Exit cdprd(const std::vector<std::string>& args, const std::string& out_path) {
  std::vector<std::string> argv{CDPR_CDPRD_BIN};
  argv.insert(argv.end(), args.begin(), args.end());
  test::Subprocess p(argv, out_path);
  Exit r;
  if (!p.started()) return r;
  r.status = p.wait(std::chrono::seconds(60)).value_or(-1);
  r.output = read(out_path);
  return r;
}

TEST_F(ConfigCheck, CdprdCheckConfigExitsZeroOnAValidConfigurationWithoutTheBus) {
  // can_interface names no interface: a start would fail on it, the check does not open it.
  write("cdprd.yaml", daemon_ + "can_interface: nosuchcan0\n");
  const Exit r = cdprd({"--config", path("cdprd.yaml"), "--check-config"}, path("out.txt"));
  EXPECT_EQ(r.status, 0) << r.output;
  EXPECT_NE(r.output.find("valid"), std::string::npos) << r.output;
}

TEST_F(ConfigCheck, CdprdCheckConfigNamesEveryErrorAndExitsTwo) {
  write("robot.yaml", mini_in_millimetres());
  write("cdprd.yaml", replaced(daemon_, "cdprd.sock}", "cdprd.sock, group: no-such-group-cdpr}"));
  const Exit r = cdprd({"--config", path("cdprd.yaml"), "--check-config"}, path("out.txt"));
  EXPECT_EQ(r.status, 2) << r.output;
  EXPECT_NE(r.output.find("looks like mm"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("no group 'no-such-group-cdpr'"), std::string::npos) << r.output;
}

TEST_F(ConfigCheck, CdprdChecksTheFilesBeforeItOpensTheBus) {
  // A start (no --check-config) on an interface that does not exist: the robot file's error is
  // named, not the CAN interface's, and nothing after it is tried.
  write("robot.yaml", mini_in_millimetres());
  write("cdprd.yaml", daemon_ + "can_interface: nosuchcan0\n");
  const Exit r = cdprd({"--config", path("cdprd.yaml")}, path("out.txt"));
  EXPECT_EQ(r.status, 2) << r.output;
  EXPECT_NE(r.output.find("looks like mm"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("CAN interface"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(path("state"))) << "the state directory was created";
}

}  // namespace
}  // namespace cdpr::controller
