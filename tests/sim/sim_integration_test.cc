// cdpr-sim as a process: its laser slave read by mbpoll (an independent Modbus master) and by the
// project's own driver, over the pty it creates and over TCP; --can without a network or an
// interface; the lock-step mode end to end (pose list in, recording out).
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <regex>
#include <string>
#include <thread>
#include <vector>

#include "cdpr/modbus/laser_sensor.hpp"
#include "cdpr/recording/recording.hpp"
#include "peer_process.hpp"

namespace {

using cdpr::modbus::testing::ChildProcess;
using cdpr::modbus::testing::read_text;
using cdpr::modbus::testing::TempDir;
using cdpr::modbus::testing::wait_for_file;

const std::string kSource = CDPR_SOURCE_DIR;
const std::string kSim = CDPR_SIM_EXE;

// Runs a shell command, returns its exit status and output (stdout + stderr).
int run(const std::string& cmd, std::string& out) {
  out.clear();
  FILE* p = popen((cmd + " 2>&1").c_str(), "r");
  if (p == nullptr) return -1;
  char buf[512];
  while (std::fgets(buf, sizeof buf, p) != nullptr) out += buf;
  const int st = pclose(p);
  return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

// A noise-free copy of mini-none.yaml (so every reading equals the printed true distance).
std::string write_scenario(const TempDir& dir) {
  const std::string path = dir.file("scenario.yaml");
  std::ofstream(path) << "name: it\n"
                      << "truth: {config: " << kSource << "/config/mini-measured.yaml}\n"
                      << "laser:\n  register_map: " << kSource
                      << "/config/lasers/baumer-om20-om30.yaml\n"
                      << "  slave_id: 1\n  baud: 115200\n  parity: none\n";
  return path;
}

// Waits until `log` holds a line matching `re`, returns its first capture ("" on timeout).
std::string wait_for_line(const std::string& log, const std::regex& re, double timeout_s) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  while (std::chrono::steady_clock::now() < end) {
    std::smatch m;
    const std::string text = read_text(log);
    if (std::regex_search(text, m, re)) return m[1].str();
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  return "";
}

// The float value mbpoll prints for one register pair ("[203]: 	549.98").
double mbpoll_value(const std::string& out) {
  std::smatch m;
  if (!std::regex_search(out, m, std::regex(R"(\[\d+\]:\s*([-+0-9.eE]+))"))) return NAN;
  return std::stod(m[1].str());
}

struct Sim {
  TempDir dir;
  ChildProcess proc;
  std::string log = dir.file("sim.log");
  double true_distance = NAN;

  bool start(const std::vector<std::string>& extra) {
    std::vector<std::string> argv = {
        kSim,     "--config", kSource + "/config/mini.yaml", "--scenario", write_scenario(dir),
        "--seed", "3"};
    argv.insert(argv.end(), extra.begin(), extra.end());
    auto p = ChildProcess::spawn(argv, log);
    if (!p.ok()) return false;
    proc = std::move(*p);
    const std::string d =
        wait_for_line(log, std::regex(R"(true laser distance ([0-9.]+) m)"), 30.0);
    if (d.empty()) return false;
    true_distance = std::stod(d);
    return true;
  }
};

TEST(SimProcess, MbpollAndTheDriverReadTheLaserOverThePty) {
  Sim sim;
  const std::string link = sim.dir.file("laser");
  ASSERT_TRUE(sim.start({"--modbus", "rtu:" + link})) << read_text(sim.log);
  ASSERT_TRUE(wait_for_file(link, 30.0));
  // MINI at home: the floor is ~0.55 m below the laser.
  EXPECT_NEAR(sim.true_distance, 0.55, 0.01);
  std::string out;
  // Baumer map: float32 in mm at PDU 202-203, low word first (mbpoll's default order).
  const int rc =
      run("mbpoll -m rtu -b 115200 -P none -a 1 -t 3:float -0 -r 202 -c 1 -1 -o 10 " + link, out);
  ASSERT_EQ(rc, 0) << out;
  EXPECT_NEAR(mbpoll_value(out), sim.true_distance * 1000.0, 1e-3) << out;

  cdpr::modbus::LaserConfig c;
  auto map = cdpr::modbus::load_register_map(kSource + "/config/lasers/baumer-om20-om30.yaml");
  ASSERT_TRUE(map.ok());
  c.map = *map;
  c.link.transport = cdpr::modbus::RtuSettings{link, 115200, 'N', 8, 1, false};
  c.link.slave_id = 1;
  c.link.response_timeout_s = 5.0;  // generous: the sim answers, however loaded the host
  cdpr::modbus::LaserSensor laser(c);
  const auto r = laser.read_once();
  ASSERT_TRUE(r.ok()) << r.error.to_string();
  EXPECT_NEAR(r.distance_m, sim.true_distance, 1e-6);
}

TEST(SimProcess, MbpollAndTheDriverReadTheLaserOverTcp) {
  Sim sim;
  ASSERT_TRUE(sim.start({"--modbus", "tcp:0"})) << read_text(sim.log);
  const std::string port = wait_for_line(sim.log, std::regex(R"(laser tcp port (\d+))"), 30.0);
  ASSERT_FALSE(port.empty()) << read_text(sim.log);
  std::string out;
  const int rc =
      run("mbpoll -m tcp -p " + port + " -a 1 -t 3:float -0 -r 202 -c 1 -1 -o 10 127.0.0.1", out);
  ASSERT_EQ(rc, 0) << out;
  EXPECT_NEAR(mbpoll_value(out), sim.true_distance * 1000.0, 1e-3) << out;
  // Big-endian word order (-B) reads the same registers as a different, wrong number.
  run("mbpoll -m tcp -p " + port + " -a 1 -t 3:float -B -0 -r 202 -c 1 -1 -o 10 127.0.0.1", out);
  EXPECT_GT(std::abs(mbpoll_value(out) - sim.true_distance * 1000.0), 1.0) << out;

  cdpr::modbus::LaserConfig c;
  auto map = cdpr::modbus::load_register_map(kSource + "/config/lasers/baumer-om20-om30.yaml");
  ASSERT_TRUE(map.ok());
  c.map = *map;
  c.link.transport = cdpr::modbus::TcpSettings{"127.0.0.1", std::stoi(port)};
  c.link.slave_id = 1;
  cdpr::modbus::LaserSensor laser(c);
  const auto r = laser.read_once();
  ASSERT_TRUE(r.ok()) << r.error.to_string();
  EXPECT_NEAR(r.distance_m, sim.true_distance, 1e-6);
}

TEST(SimProcess, CanNeedsTheNetworkAndAnExistingInterface) {
  const std::string base = kSim + " --config " + kSource + "/config/mini.yaml --scenario " +
                           kSource + "/config/scenarios/mini-none.yaml --can ";
  std::string out;
  int rc = run(base + "vcan0", out);
  EXPECT_EQ(rc, 1);
  EXPECT_NE(out.find("--can needs --canopen"), std::string::npos) << out;
  // The CANopen slaves themselves run on vcan0 in the vcan test sim_can_vcan; here the interface
  // does not exist (or the kernel has no CAN at all), and the message names it.
  rc = run(base + "cdprnocan7 --canopen " + kSource + "/config/canopen-mini.yaml", out);
  EXPECT_EQ(rc, 1);
  EXPECT_NE(out.find("cdprnocan7"), std::string::npos) << out;
  EXPECT_EQ(out.find("not built yet"), std::string::npos) << out;
}

TEST(SimProcess, ReportsBadScenarioWithFileAndLine) {
  TempDir dir;
  const std::string bad = dir.file("bad.yaml");
  std::ofstream(bad) << "name: x\neffects:\n  hooke: {ea: -1}\n";
  std::string out;
  const int rc = run(
      kSim + " --config " + kSource + "/config/mini.yaml --scenario " + bad + " --modbus rtu", out);
  EXPECT_EQ(rc, 1);
  EXPECT_NE(out.find("bad.yaml:3: effects.hooke.ea"), std::string::npos) << out;
}

// Issue 16 item 10: usage errors exit 2 (CLI11's own codes 105, 106, 109 before), --version.
TEST(SimProcess, UsageErrorsExitWithTwoAndVersionWithZero) {
  std::string out;
  EXPECT_EQ(run(kSim, out), 2) << out;  // --config and --scenario missing
  EXPECT_EQ(run(kSim + " --config a.yaml --scenario b.yaml --no-such-option", out), 2) << out;
  EXPECT_EQ(run(kSim + " --config a.yaml --scenario b.yaml --rate 0", out), 2) << out;
  EXPECT_EQ(run(kSim + " --config a.yaml --scenario b.yaml --home sideways", out), 2) << out;
  EXPECT_EQ(run(kSim + " --version", out), 0) << out;
  EXPECT_EQ(out.rfind("cdpr-sim 0.", 0), 0u) << out;
}

// Issue 16 item 2: the recording written by --lockstep never replaces an input.
TEST(SimProcess, LockstepRefusesAnOutputThatIsAnInput) {
  TempDir dir;
  cdpr::recording::PoseList poses;
  poses.poses.push_back(cdpr::Pose{});
  const std::string pose_file = dir.file("poses.csv");
  ASSERT_TRUE(cdpr::recording::write_pose_list(poses, pose_file).ok());
  const std::string before = read_text(pose_file);
  // The scenario's true robot is a copy: were the check missing, the shipped file stays intact.
  const std::string truth = dir.file("truth.yaml");
  std::ofstream(truth) << read_text(kSource + "/config/mini-measured.yaml");
  const std::string scenario = dir.file("scenario.yaml");
  std::ofstream(scenario) << "name: it\ntruth: {config: " << truth << "}\n";
  const std::string base = kSim + " --config " + kSource + "/config/mini.yaml --scenario " +
                           scenario + " --lockstep " + pose_file + " --out ";
  std::string out;
  EXPECT_EQ(run(base + pose_file, out), 2) << out;
  EXPECT_NE(out.find("--lockstep"), std::string::npos) << out;
  EXPECT_EQ(run(base + scenario, out), 2) << out;
  EXPECT_NE(out.find("--scenario"), std::string::npos) << out;
  EXPECT_EQ(run(base + truth, out), 2) << out;
  EXPECT_NE(out.find("truth.config"), std::string::npos) << out;
  EXPECT_EQ(read_text(pose_file), before);
  EXPECT_EQ(read_text(truth), read_text(kSource + "/config/mini-measured.yaml"));
}

TEST(SimProcess, LockstepWritesARecording) {
  TempDir dir;
  cdpr::recording::PoseList poses;
  poses.metadata.set("units", "SI");
  for (int k = 0; k < 6; ++k) {
    cdpr::Pose p;
    p.position = Eigen::Vector3d(0.04 * std::cos(k), 0.03 * std::sin(k), 0.02 * (k % 3 - 1));
    p.rpy = Eigen::Vector3d(0.01 * (k % 2), -0.01 * (k % 3 == 0), 0.02 * std::sin(k));
    poses.poses.push_back(p);
  }
  const std::string pose_file = dir.file("poses.csv");
  ASSERT_TRUE(cdpr::recording::write_pose_list(poses, pose_file).ok());
  auto lockstep = [&](const std::string& out_file) {
    std::string out;
    const int rc = run(kSim + " --config " + kSource + "/config/mini.yaml --scenario " + kSource +
                           "/config/scenarios/mini-hooke.yaml --seed 11 --lockstep " + pose_file +
                           " --out " + out_file + " --laser-samples 4",
                       out);
    EXPECT_EQ(rc, 0) << out;
    return out;
  };
  const std::string out = lockstep(dir.file("a.csv"));
  EXPECT_NE(out.find("6 poses"), std::string::npos) << out;
  lockstep(dir.file("b.csv"));
  auto a = cdpr::recording::read_recording(dir.file("a.csv"));
  auto b = cdpr::recording::read_recording(dir.file("b.csv"));
  ASSERT_TRUE(a.ok()) << a.status().to_string();
  ASSERT_TRUE(b.ok()) << b.status().to_string();
  ASSERT_EQ(a->poses.size(), 6u);
  EXPECT_EQ(a->num_cables, 8);
  EXPECT_EQ(a->metadata.get("source"), "simulated");
  EXPECT_EQ(a->metadata.get("seed"), "11");
  for (std::size_t j = 0; j < 6; ++j) {
    EXPECT_TRUE(a->poses[j].lengths.allFinite());
    EXPECT_TRUE(a->poses[j].tensions.allFinite());
    EXPECT_TRUE(std::isfinite(a->poses[j].lasers(0)));
    // The cables hold the 2 kg platform (slack cables read 0 N plus noise).
    EXPECT_GT(a->poses[j].tensions.sum(), 2.0 * 9.81);
    EXPECT_GT(a->poses[j].tensions.minCoeff(), -1.0);
    // Deterministic by seed: the same numbers twice.
    EXPECT_EQ(a->poses[j].lengths, b->poses[j].lengths);
    EXPECT_EQ(a->poses[j].lasers, b->poses[j].lasers);
  }
}

}  // namespace
