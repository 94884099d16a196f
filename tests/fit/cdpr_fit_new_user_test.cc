// cdpr-fit as a new user meets it (issue 16): one regression test per finding. The real binary
// runs as a separate process on the shipped MINI configs; every check is made on what the user
// sees (exit status, stderr, stdout, the files left behind), independently of the tool's code.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "fit_process.hpp"

namespace cdpr::fit_test {
namespace {

void write(const std::string& path, const std::string& text) {
  std::ofstream(path, std::ios::binary) << text;
}

std::vector<std::string> lines_of(const std::string& text) {
  std::vector<std::string> v;
  std::size_t start = 0;
  while (start < text.size()) {
    std::size_t nl = text.find('\n', start);
    if (nl == std::string::npos) nl = text.size();
    v.push_back(text.substr(start, nl - start));
    start = nl + 1;
  }
  return v;
}

std::string join_lines(const std::vector<std::string>& lines) {
  std::string s;
  for (const std::string& l : lines) s += l + "\n";
  return s;
}

// The recording with one cell replaced: `column` of the `row`-th data row (0-based).
std::string with_cell(const std::string& recording, const std::string& column, int row,
                      const std::string& value, int* line = nullptr) {
  std::vector<std::string> lines = lines_of(recording);
  std::size_t header = 0;
  while (header < lines.size() && (lines[header].empty() || lines[header][0] == '#')) ++header;
  std::vector<std::string> names;
  for (std::size_t s = 0, c; s <= lines[header].size(); s = c + 1) {
    c = lines[header].find(',', s);
    if (c == std::string::npos) c = lines[header].size();
    names.push_back(lines[header].substr(s, c - s));
  }
  const auto col =
      static_cast<std::size_t>(std::find(names.begin(), names.end(), column) - names.begin());
  std::string& l = lines[header + 1 + static_cast<std::size_t>(row)];
  std::vector<std::string> cells;
  for (std::size_t s = 0, c; s <= l.size(); s = c + 1) {
    c = l.find(',', s);
    if (c == std::string::npos) c = l.size();
    cells.push_back(l.substr(s, c - s));
  }
  cells[col] = value;
  l.clear();
  for (std::size_t i = 0; i < cells.size(); ++i) l += (i ? "," : "") + cells[i];
  if (line != nullptr) *line = static_cast<int>(header + 2 + static_cast<std::size_t>(row));
  return join_lines(lines);
}

class NewUser : public FitProcessTest {
 protected:
  NewUser() : FitProcessTest("cdpr_fit_new_user_") {}

  // The documented session's first two steps: designed poses, an elastic recording of the
  // measured MINI from the nominal config.
  std::string record(int count = 25) {
    ProcessResult r = fit({"design-poses", "--config", kNominal, "--count", std::to_string(count),
                           "--out", path("poses.csv")});
    EXPECT_EQ(r.status, 0) << r.err;
    r = fit({"simulate", "--config", kTruth, "--nominal", kNominal, "--physics", "elastic",
             "--poses", path("poses.csv"), "--noise-laser", "0.001", "--noise-length", "1e-4",
             "--noise-force", "1", "--seed", "42", "--out", path("rec.csv")});
    EXPECT_EQ(r.status, 0) << r.err;
    return path("rec.csv");
  }
};

// ---- item 1: bytes that are not UTF-8 never crash, on the error and the success path ----------

TEST_F(NewUser, InvalidUtf8InACellGivesAJsonErrorNotACrash) {
  write(path("p.csv"), "# units: SI\npose,x,y,z,roll,pitch,yaw\n0,\xff,0,0,0,0,0\n");
  const ProcessResult r = fit({"--json", "simulate", "--config", kNominal, "--poses", path("p.csv"),
                               "--out", path("x.csv")});
  EXPECT_EQ(r.status, 1) << r.err;
  const auto j = nlohmann::json::parse(r.out);  // throws (fails the test) when not valid JSON
  EXPECT_FALSE(j["ok"].get<bool>());
  EXPECT_THAT(j["error"]["message"].get<std::string>(), HasSubstr("p.csv:3: column 2 (x)"));
  EXPECT_FALSE(fs::exists(path("x.csv")));
}

TEST_F(NewUser, InvalidUtf8InARobotNameAndAPathStillGivesJsonReports) {
  std::string config = slurp(kNominal);
  config.replace(config.find("name: MINI"), 10, "name: MINI\xff\xfe");
  const std::string odd = path("mini-\xff.yaml");
  write(odd, config);
  const std::string rec = record(16);
  ProcessResult r = fit({"--json", "calibrate", "--config", odd, "--recording", rec, "--out",
                         path("cal.yaml"), "--report", path("report.json")});
  ASSERT_NE(r.status, -1) << "killed by a signal: " << r.err;
  EXPECT_EQ(r.status, 0) << r.err;
  const auto printed = nlohmann::json::parse(r.out);
  const auto written = nlohmann::json::parse(slurp(path("report.json")));
  EXPECT_TRUE(printed["ok"].get<bool>());
  EXPECT_THAT(written.dump(), HasSubstr("mini-\xef\xbf\xbd.yaml"));  // U+FFFD for the 0xFF
  r = fit({"--json", "simulate", "--config", odd, "--design", "6", "--out", path("sim.csv")});
  EXPECT_EQ(r.status, 0) << r.err;
  EXPECT_TRUE(nlohmann::json::parse(r.out)["ok"].get<bool>());
}

// ---- item 2: an output never replaces an input or another output -------------------------------

TEST_F(NewUser, OutputsNamingAnInputOrAnotherOutputAreRefusedWithExitTwo) {
  const std::string rec = record(16);
  const std::string before = slurp(rec);
  struct Case {
    std::vector<std::string> args;
    std::string named;
  };
  fs::copy_file(kNominal, path("nominal.yaml"));
  const std::vector<Case> cases = {
      {{"calibrate", "--config", kNominal, "--recording", rec, "--out", rec}, "--recording"},
      {{"calibrate", "--config", kNominal, "--recording", rec, "--report", "./rec.csv"},
       "--recording"},
      {{"calibrate", "--config", path("nominal.yaml"), "--recording", rec, "--out",
        path("nominal.yaml")},
       "--config"},
      {{"calibrate", "--config", kNominal, "--recording", rec, "--out", path("x.yaml"), "--report",
        path("x.yaml")},
       "--out"},
      {{"simulate", "--config", kTruth, "--poses", path("poses.csv"), "--out", path("poses.csv")},
       "--poses"},
      {{"design-poses", "--config", path("nominal.yaml"), "--out", path("nominal.yaml")},
       "--config"},
      {{"diagnose", "--config", kNominal, "--recording", rec, "--html", rec}, "--recording"},
  };
  for (const Case& c : cases) {
    const std::string poses_before = slurp(path("poses.csv"));
    const ProcessResult r = fit(c.args, /*in_dir=*/true);
    EXPECT_EQ(r.status, 2) << c.args[0] << " " << r.err;
    EXPECT_THAT(r.err, HasSubstr(c.named)) << r.err;
    EXPECT_THAT(r.err, HasSubstr("same file")) << r.err;
    EXPECT_EQ(slurp(rec), before);
    EXPECT_EQ(slurp(path("poses.csv")), poses_before);
    EXPECT_EQ(slurp(path("nominal.yaml")), slurp(kNominal));
    EXPECT_FALSE(fs::exists(path("x.yaml")));
  }
}

// ---- item 3: a failed command leaves no new file -----------------------------------------------

TEST_F(NewUser, AReportThatCannotBeWrittenLeavesNoConfigBehind) {
  const std::string rec = record(16);
  const ProcessResult r = fit({"calibrate", "--config", kNominal, "--recording", rec, "--out",
                               path("cal.yaml"), "--report", path("no-such-dir/report.json")});
  EXPECT_EQ(r.status, 1) << r.err;
  EXPECT_THAT(r.err, HasSubstr("no-such-dir"));
  EXPECT_FALSE(fs::exists(path("cal.yaml")));
  for (const auto& e : fs::directory_iterator(dir_)) {
    EXPECT_THAT(e.path().filename().string(), Not(HasSubstr(".tmp-")));  // no temporaries
  }
}

// ---- item 4: calibrate refuses millimetres under "# units: SI" as diagnose does ----------------

TEST_F(NewUser, CalibrateRefusesLengthsInMillimetres) {
  const std::string rec = record(16);
  std::string text = slurp(rec);
  // Scale the length columns by 1000 with the recording library's view of the file.
  std::vector<std::string> lines = lines_of(text);
  std::size_t header = 0;
  while (lines[header].empty() || lines[header][0] == '#') ++header;
  for (std::size_t l = header + 1; l < lines.size(); ++l) {
    std::vector<std::string> cells;
    for (std::size_t s = 0, c; s <= lines[l].size(); s = c + 1) {
      c = lines[l].find(',', s);
      if (c == std::string::npos) c = lines[l].size();
      cells.push_back(lines[l].substr(s, c - s));
    }
    for (std::size_t c = 8; c < 16; ++c) cells[c] = std::to_string(std::stod(cells[c]) * 1000.0);
    lines[l].clear();
    for (std::size_t c = 0; c < cells.size(); ++c) lines[l] += (c ? "," : "") + cells[c];
  }
  write(path("mm.csv"), join_lines(lines));
  const ProcessResult r = fit({"calibrate", "--config", kNominal, "--recording", path("mm.csv"),
                               "--out", path("cal.yaml")});
  EXPECT_EQ(r.status, 1) << r.out;
  EXPECT_THAT(r.err, HasSubstr("mm.csv: length_1..length_8: looks like mm, expected m"));
  EXPECT_FALSE(fs::exists(path("cal.yaml")));
}

// ---- item 5: extreme numbers are refused at the reader, naming line and column, in one line ----

TEST_F(NewUser, ExtremeNumbersAreRefusedAtTheReaderInOneReadableLine) {
  const std::string rec = slurp(record(16));
  struct Case {
    std::string column, value, expect;
  };
  const std::vector<Case> cases = {
      {"cmd_x", "1e300", "column 3 (cmd_x): 1e+300 m is outside"},
      {"length_2", "-1e308", "(length_2): -1e+308 m is outside"},
      {"tension_1", "1e200", "(tension_1): 1e+200 N is outside"},
      // found by fuzz_cli.py: a zero length made diagnose run 30 s
      {"length_7", "-0", "(length_7): -0 m is outside the plausible range (0, "}};
  for (const Case& c : cases) {
    int line = 0;
    write(path("bad.csv"), with_cell(rec, c.column, 3, c.value, &line));
    const ProcessResult r =
        fit({"calibrate", "--config", kNominal, "--recording", path("bad.csv")});
    EXPECT_EQ(r.status, 1) << r.err;
    EXPECT_THAT(r.err, HasSubstr("bad.csv:" + std::to_string(line) + ":")) << r.err;
    EXPECT_THAT(r.err, HasSubstr(c.expect)) << r.err;
    EXPECT_EQ(lines_of(r.err).size(), 1u) << r.err;  // no solver dump
    EXPECT_LT(r.err.size(), 400u) << r.err;          // bounds printed readably
  }
  std::string noisy = rec;
  const std::size_t k = noisy.find("# noise_length_m: ");
  ASSERT_NE(k, std::string::npos);
  noisy.replace(k, noisy.find('\n', k) - k, "# noise_length_m: 1e300");
  write(path("noisy.csv"), noisy);
  const ProcessResult r = fit({"diagnose", "--config", kNominal, "--recording", path("noisy.csv")});
  EXPECT_EQ(r.status, 1) << r.err;
  EXPECT_THAT(r.err, HasSubstr("noise_length_m: 1e+300 m is outside the plausible range"));
  EXPECT_EQ(lines_of(r.err).size(), 1u) << r.err;
}

// ---- item 7: long work shows its progress; sizes that take very long are refused or announced -

TEST_F(NewUser, LongWorkShowsProgressWithAnEstimate) {
  ProcessResult r = fit({"--progress", "always", "design-poses", "--config", kNominal, "--count",
                         "12", "--out", path("poses.csv")});
  EXPECT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.err, HasSubstr("cdpr-fit: poses designed 12/12 (100 %)"));
  EXPECT_THAT(r.err, HasSubstr("s left"));
  r = fit({"--progress", "always", "simulate", "--config", kTruth, "--nominal", kNominal,
           "--physics", "elastic", "--poses", path("poses.csv"), "--out", path("rec.csv")});
  ASSERT_EQ(r.status, 0) << r.err;
  r = fit(
      {"--progress", "always", "calibrate", "--config", kNominal, "--recording", path("rec.csv")});
  EXPECT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.err, HasSubstr("cdpr-fit: solver iteration "));
  EXPECT_THAT(r.err, HasSubstr("(at most 100)"));
  r = fit({"--progress", "always", "diagnose", "--config", kNominal, "--recording", path("rec.csv"),
           "--bootstrap", "10", "--folds", "2"});
  EXPECT_NE(r.status, -1) << r.err;
  EXPECT_THAT(r.err, HasSubstr("cdpr-fit: bootstrap resamples 10/10 (100 %)"));
  // Not a terminal, not asked for: no progress line (stderr stays for messages).
  r = fit({"design-poses", "--config", kNominal, "--count", "12", "--out", path("p2.csv")});
  EXPECT_EQ(r.err, "");
  // Sizes: refused above 20 points per axis, announced above 12.
  r = fit(
      {"design-poses", "--config", kNominal, "--points-per-axis", "50", "--out", path("p3.csv")});
  EXPECT_EQ(r.status, 2) << r.err;
  EXPECT_FALSE(fs::exists(path("p3.csv")));
}

// ---- item 8: the documented happy path ends without a warning ----------------------------------

TEST_F(NewUser, TheDocumentedSessionEndsWithoutWarnings) {
  const std::string rec = record(25);
  const ProcessResult r =
      fit({"calibrate", "--config", kNominal, "--recording", rec, "--out", path("calibrated.yaml"),
           "--report", path("report.json"), "--truth", kTruth});
  EXPECT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(r.err, "");
  EXPECT_THAT(r.out, HasSubstr("Solver: no warnings."));
  EXPECT_THAT(r.out, Not(HasSubstr("Warnings:")));  // none about the inputs either
  EXPECT_THAT(r.out, Not(HasSubstr("Solver warnings:")));
  const auto j = nlohmann::json::parse(slurp(path("report.json")));
  EXPECT_TRUE(j["warnings"].empty()) << j["warnings"].dump();
}

// The documented session's simulate --physics elastic settles every designed pose; and so does a
// wider design (+-0.3 m, 10 points per axis: it once stopped at pose 22, "no equilibrium found
// ... 3 of 8 cables taut") and a pose 16 cm from home that the elastic solver could not settle
// (all 8 true cables slack at the commanded pose) while the virtual robot, cdpr-sim, settles
// both: simulate must settle every pose that cdpr-sim settles.
TEST_F(NewUser, SimulateElasticSettlesEveryPoseTheVirtualRobotSettles) {
  record(25);  // design-poses and simulate --physics elastic as documented: both exit 0
  ProcessResult r = fit({"design-poses", "--config", kNominal, "--count", "25", "--half-extent",
                         "0.3", "--points-per-axis", "10", "--out", path("wide.csv")});
  ASSERT_EQ(r.status, 0) << r.err;
  write(path("near.csv"),
        "# units: SI\npose,x,y,z,roll,pitch,yaw\n0,0,0,0,0,0,0\n"
        "1,0.121434,0.00432455,-0.102016,0.0914907,0.000811753,0.0727556\n");
  write(path("truth.yaml"), "name: mini-measured\ntruth:\n  config: " + kTruth + "\n");
  for (const std::string poses : {"wide.csv", "near.csv"}) {
    const std::string sim = cdpr::fit_test::quote(CDPR_SIM_BIN) + " --config " +
                            cdpr::fit_test::quote(kNominal) + " --scenario " +
                            cdpr::fit_test::quote(path("truth.yaml")) + " --lockstep " +
                            cdpr::fit_test::quote(path(poses)) + " --out " +
                            cdpr::fit_test::quote(path("sim-" + poses)) + " >/dev/null 2>&1";
    ASSERT_EQ(std::system(sim.c_str()), 0) << "cdpr-sim does not settle " << poses;
    r = fit({"simulate", "--config", kTruth, "--nominal", kNominal, "--physics", "elastic",
             "--poses", path(poses), "--out", path("rec-" + poses)});
    EXPECT_EQ(r.status, 0) << poses << ": " << r.err;
    EXPECT_THAT(r.err, Not(HasSubstr("equilibrium"))) << poses;
    EXPECT_TRUE(fs::exists(path("rec-" + poses))) << poses;
  }
}

// The default rigid physics puts the platform exactly at each pose: a designed pose outside the
// measured robot's wrench-feasible workspace is refused, and the message says what to use.
TEST_F(NewUser, RigidSimulateOutsideTheWorkspaceNamesThePoseAndSuggestsElasticPhysics) {
  ProcessResult r =
      fit({"design-poses", "--config", kNominal, "--count", "25", "--out", path("poses.csv")});
  ASSERT_EQ(r.status, 0) << r.err;
  r = fit(
      {"simulate", "--config", kTruth, "--poses", path("poses.csv"), "--out", path("rigid.csv")});
  if (r.status == 0) GTEST_SKIP() << "every designed pose is inside the measured robot's workspace";
  EXPECT_EQ(r.status, 1) << r.err;
  EXPECT_THAT(r.err, HasSubstr("outside the wrench-feasible workspace"));
  EXPECT_THAT(r.err, HasSubstr("with --physics elastic --nominal"));
  EXPECT_FALSE(fs::exists(path("rigid.csv")));
}

// ---- item 9: diagnose says each thing once ------------------------------------------------------

TEST_F(NewUser, DiagnoseOnCleanDataStatesItsVerdictOnceAndChasesNoSuspect) {
  const std::string rec = record(25);
  const ProcessResult r = fit({"diagnose", "--config", kNominal, "--recording", rec});
  EXPECT_EQ(r.status, 0) << r.err;
  std::size_t consistent = 0;
  for (std::size_t at = r.out.find("consistent with the"); at != std::string::npos;
       at = r.out.find("consistent with the", at + 1)) {
    ++consistent;
  }
  EXPECT_EQ(consistent, 1u) << r.out;
  EXPECT_THAT(r.out, Not(HasSubstr("Suspected, not proven"))) << r.out;
}

// ---- item 10: the small ones -------------------------------------------------------------------

TEST_F(NewUser, AByteOrderMarkIsAccepted) {
  const std::string rec = slurp(record(16));
  write(path("bom.csv"), "\xEF\xBB\xBF" + rec);
  write(path("bom-poses.csv"),
        "\xEF\xBB\xBF# units: SI\npose,x,y,z,roll,pitch,yaw\n0,0,0,0,0,0,0\n");
  ProcessResult r = fit({"calibrate", "--config", kNominal, "--recording", path("bom.csv")});
  EXPECT_EQ(r.status, 0) << r.err;
  r = fit({"predict-accuracy", "--config", kNominal, "--poses", path("bom-poses.csv")});
  EXPECT_THAT(r.err, Not(HasSubstr("header"))) << r.err;
  EXPECT_THAT(r.err, Not(HasSubstr("units"))) << r.err;
}

TEST_F(NewUser, AnAbsurdGravityIsRefusedNamingIt) {
  const ProcessResult r =
      fit({"fit-force-sensor", "--experiment", kSource + "/config/examples/force-experiment.csv",
           "--gravity", "1e308"});
  EXPECT_EQ(r.status, 1) << r.err;
  EXPECT_THAT(r.err, HasSubstr("gravity 1e+308 m/s^2 (--gravity) is outside the plausible range"));
}

TEST_F(NewUser, VersionIsPrintedAndExitsZero) {
  const ProcessResult r = fit({"--version"});
  EXPECT_EQ(r.status, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("cdpr-fit 0.1"));
}

}  // namespace
}  // namespace cdpr::fit_test
