// The fault matrix (issue 17): every fault injected in every phase of cdprd's work, the outcome
// observed and written as a table. The table is generated here and committed as
// docs/reliability.md; the test fails when a cell's outcome differs from the committed table (run
// with CDPR_UPDATE_RELIABILITY=1 to rewrite the rows run after a deliberate change), and when a
// cell ends unsafe (the robot not stopped or held, the geometry changed, the recording lost, no way
// back).
//
// Most cells run in-process (tests/daemon/virtual_cell.hpp: cdprd's Daemon and the virtual robot
// on the in-process bus with a manual clock, faults injected on demand at the chosen moment).
// The process-level cells fork: a child process runs the cell and is SIGKILLed mid-phase, the
// parent restarts the daemon on the same state directory; disk full is RLIMIT_FSIZE; a power loss
// during a save is a forked writer killed while it writes the temporary file (before the rename).
//
// Each row is a test of its own
// (Row/FaultMatrix.EveryPhaseEndsSafeAndMatchesDocsReliability/<Fault>), so that CTest runs rows
// side by side; FaultMatrixTable checks that the committed table has the matrix's rows and no
// other. CDPR_MATRIX_ONLY=<substring of a fault's name> runs only those rows (and does not
// compare), as --gtest_filter=*<Fault> does with the comparison.
#include <gtest/gtest.h>

#include <map>
#include <string>
#include <vector>

#include "fault_matrix_cell.hpp"

namespace cdpr::controller {
namespace {

std::vector<FaultRow> fault_rows() {
  std::vector<FaultRow> rows;
  const std::string only_startup = "n/a: SDO is used only at start-up";
  rows.push_back({"drive fault with EMCY 0x2310 (cable 3)",
                  [](Cell& c) { c.robot->drive(kCable).inject_fault(0x2310); },
                  nullptr,
                  {},
                  nullptr});
  rows.push_back({"drive silent: heartbeat lost (cable 3)",
                  [](Cell& c) { c.robot->drive(kCable).faults().silent = true; },
                  [](Cell& c) { c.robot->drive(kCable).faults().silent = false; },
                  {},
                  nullptr});
  rows.push_back(
      {"SDO abort 0x06020000 on 0x1600:00, RPDO mapping (cable 3)",
       [](Cell& c) {
         c.robot->drive(kCable).faults().abort_on[canopen::ObjectAddress{0x1600, 0}.key()] =
             0x06020000;
       },
       [](Cell& c) { c.robot->drive(kCable).faults().abort_on.clear(); },
       {{Phase::kHolding, only_startup},
        {Phase::kMoving, only_startup},
        {Phase::kMeasuring, only_startup},
        {Phase::kIdentifying, only_startup},
        {Phase::kHotSwap, only_startup}},
       nullptr});
  rows.push_back({"bus-off burst (0.3 s)",
                  [](Cell& c) {
                    c.robot->set_bus_off(true);
                    if (!c.daemon) return;  // start-up: until cleared
                    c.run_until([] { return false; }, 0.3);
                    c.robot->set_bus_off(false);
                  },
                  [](Cell& c) { c.robot->set_bus_off(false); },
                  {},
                  nullptr});
  rows.push_back({"force-sensor node silent",
                  [](Cell& c) { c.robot->node(kForceNode).faults().silent = true; },
                  [](Cell& c) { c.robot->node(kForceNode).faults().silent = false; },
                  {},
                  nullptr});
  rows.push_back({"force reading stuck (cable 3)",
                  [](Cell& c) { c.robot->set_force_fault(kCable, sim::ForceChannelFault::kStuck); },
                  [](Cell& c) { c.robot->set_force_fault(kCable, sim::ForceChannelFault::kNone); },
                  {},
                  nullptr});
  rows.push_back(
      {"force reading out of range: raw 32767 (cable 3)",
       [](Cell& c) { c.robot->set_force_fault(kCable, sim::ForceChannelFault::kRaw, 32767.0); },
       [](Cell& c) { c.robot->set_force_fault(kCable, sim::ForceChannelFault::kNone); },
       {},
       nullptr});
  auto laser = [](sim::LaserFaultMode mode) {
    return [mode](Cell& c) { c.slave->set_fault(mode); };
  };
  auto laser_ok = [](Cell& c) {
    c.slave->set_fault(sim::LaserFaultMode::kNone);
    c.laser_status.reset();
  };
  {
    FaultRow timeout{"laser timeout", laser(sim::LaserFaultMode::kTimeout), laser_ok, {}, nullptr};
    timeout.real_time = true;
    rows.push_back(timeout);
  }
  rows.push_back({"laser garbage", laser(sim::LaserFaultMode::kGarbage), laser_ok, {}, nullptr});
  rows.push_back(
      {"laser out of range", laser(sim::LaserFaultMode::kOutOfRange), laser_ok, {}, nullptr});
  rows.push_back({"laser \"no target\"",
                  [](Cell& c) { c.laser_status = sim::LaserStatus::kNoTarget; },
                  laser_ok,
                  {},
                  nullptr});
  // A cable slipping on its drum: the true cable is longer (slack) or shorter (overload) than
  // the encoder says.
  rows.push_back({"cable slack: 20 mm slip (cable 3)",
                  [](Cell& c) { c.robot->set_cable_slip(kCable, 20000.0); },
                  [](Cell& c) { c.robot->set_cable_slip(kCable, 0.0); },
                  {},
                  nullptr});
  {
    // The platform moves with the slip: it takes a long one to pass 1.1 f_max (220 N).
    FaultRow over{"cable overloaded: 250 mm slip (cable 3)",
                  [](Cell& c) { c.robot->set_cable_slip(kCable, -250000.0); },
                  [](Cell& c) { c.robot->set_cable_slip(kCable, 0.0); },
                  {},
                  nullptr};
    rows.push_back(over);
  }
  {
    // The safety chain: the e-stop input of cable 3's drive (its digital inputs in an event-driven
    // TPDO of the cell's safety network), with the holding brakes by output.
    FaultRow estop{"e-stop opened (input of drive 3), brakes by output",
                   [](Cell& c) { c.robot->set_estop(true); },
                   [](Cell& c) { c.robot->set_estop(false); },
                   {},
                   nullptr};
    estop.config =
        "safety: {estop: [{kind: drive_input, node: 3, bit: 16}], brakes: {control: "
        "output, release_delay_s: 0.05, apply_delay_s: 0.05}}\n";
    estop.safety_network = true;
    rows.push_back(estop);
  }
  rows.push_back({"cdpr-sim killed: every node and the laser silent, then the sim restarts",
                  [](Cell& c) {
                    c.robot_dead = true;
                    c.slave->set_fault(sim::LaserFaultMode::kTimeout);
                  },
                  [](Cell& c) {
                    c.robot_dead = false;
                    c.slave->set_fault(sim::LaserFaultMode::kNone);
                    c.robot->power_on(c.clock.now());  // the nodes boot again
                  },
                  {},
                  nullptr});
  {
    FaultRow kill{"SIGKILL of cdprd, then restart", nullptr, nullptr, {}, nullptr};
    kill.custom = [](Phase p) {
      const FaultRow none{"kill", nullptr, nullptr, {}, nullptr};
      MatrixCell cell(none, p);
      return cell.run_killed(false);
    };
    rows.push_back(kill);
  }
  {
    // Disk full: every write to a regular file fails (RLIMIT_FSIZE 0, SIGXFSZ ignored).
    static struct rlimit saved {};
    FaultRow full{"disk full while saving",
                  [](Cell&) {
                    ::signal(SIGXFSZ, SIG_IGN);
                    ::getrlimit(RLIMIT_FSIZE, &saved);
                    struct rlimit none = saved;
                    none.rlim_cur = 0;
                    ::setrlimit(RLIMIT_FSIZE, &none);
                  },
                  [](Cell&) { ::setrlimit(RLIMIT_FSIZE, &saved); },
                  {},
                  nullptr};
    full.not_applicable[Phase::kHolding] = "n/a: nothing is saved while holding";
    full.not_applicable[Phase::kMoving] = "n/a: nothing is saved while moving";
    full.inject_before_save = true;
    rows.push_back(full);
  }
  {
    FaultRow loss{
        "power loss during a save (kill between write and rename)", nullptr, nullptr, {}, nullptr};
    loss.not_applicable[Phase::kHolding] = "n/a: nothing is saved while holding";
    loss.not_applicable[Phase::kMoving] = "n/a: nothing is saved while moving";
    loss.custom = [](Phase p) {
      const FaultRow none{"power loss", nullptr, nullptr, {}, nullptr};
      MatrixCell cell(none, p);
      return cell.run_killed(true);
    };
    rows.push_back(loss);
  }
  return rows;
}

// The table, as markdown: one row per fault, one column per phase.
std::string table(const std::vector<FaultRow>& rows,
                  const std::map<std::pair<std::string, Phase>, std::string>& cells) {
  std::string t = "| fault |";
  for (Phase p : kPhases) t += std::string(" ") + phase_name(p) + " |";
  t += "\n| --- |";
  for (std::size_t i = 0; i < kPhases.size(); ++i) t += " --- |";
  t += "\n";
  for (const FaultRow& r : rows) {
    t += "| " + r.name + " |";
    for (Phase p : kPhases) {
      auto it = cells.find({r.name, p});
      t += " " + (it == cells.end() ? std::string("not covered") : it->second) + " |";
    }
    t += "\n";
  }
  return t;
}

// The cells of a committed table: (fault, column index) -> text.
std::map<std::pair<std::string, std::size_t>, std::string> parse_table(const std::string& text) {
  std::map<std::pair<std::string, std::size_t>, std::string> out;
  std::istringstream in(text);
  std::string line;
  const std::string begin = "<!-- fault matrix: generated -->";
  bool inside = false;
  while (std::getline(in, line)) {
    if (line == begin) inside = true;
    if (line == "<!-- end of the generated fault matrix -->") break;
    if (!inside || line.rfind("| ", 0) != 0 || line.rfind("| fault |", 0) == 0) continue;
    std::vector<std::string> fields;
    std::size_t pos = 1;
    while (pos < line.size()) {
      const std::size_t bar = line.find(" |", pos);
      if (bar == std::string::npos) break;
      std::string f = line.substr(pos, bar - pos);
      while (!f.empty() && f.front() == ' ') f.erase(f.begin());
      fields.push_back(f);
      pos = bar + 2;
    }
    if (fields.size() < 2) continue;
    for (std::size_t i = 1; i < fields.size(); ++i) out[{fields[0], i - 1}] = fields[i];
  }
  return out;
}

const std::vector<FaultRow>& all_rows() {
  static const std::vector<FaultRow> rows = fault_rows();
  return rows;
}

// The committed table (docs/reliability.md) by fault and phase; empty when the file is missing.
std::map<std::pair<std::string, Phase>, std::string> committed_cells() {
  std::map<std::pair<std::string, Phase>, std::string> out;
  auto committed = read_text_file(kSource + "/docs/reliability.md");
  if (!committed.ok()) return out;
  for (const auto& [key, text] : parse_table(*committed)) {
    if (key.second < kPhases.size()) out[{key.first, kPhases[key.second]}] = text;
  }
  return out;
}

// A committed cell's outcomes: a cell whose outcome depends on the timing of real threads (the
// laser driver polls in real time while the robot's clock is manual) lists them separated by
// " OR ".
std::vector<std::string> alternatives(const std::string& cell) {
  std::vector<std::string> allowed;
  for (std::size_t from = 0;;) {
    const std::size_t at = cell.find(" OR ", from);
    allowed.push_back(cell.substr(from, at == std::string::npos ? std::string::npos : at - from));
    if (at == std::string::npos) return allowed;
    from = at + 4;
  }
}

// Replaces the generated table in docs/reliability.md by the committed cells with `row`'s
// replaced (a committed cell whose alternatives include the new outcome is kept as it is).
void rewrite_row(const FaultRow& row, const std::map<Phase, std::string>& got) {
  const std::string doc_path = kSource + "/docs/reliability.md";
  auto committed = read_text_file(doc_path);
  ASSERT_TRUE(committed.ok()) << doc_path;
  auto cells = committed_cells();
  for (const auto& [phase, text] : got) {
    auto it = cells.find({row.name, phase});
    if (it != cells.end()) {
      const auto allowed = alternatives(it->second);
      if (std::find(allowed.begin(), allowed.end(), text) != allowed.end()) continue;
    }
    cells[{row.name, phase}] = text;
  }
  const std::string begin = "<!-- fault matrix: generated -->\n";
  const std::string end = "<!-- end of the generated fault matrix -->\n";
  const std::size_t a = committed->find(begin), b = committed->find(end);
  ASSERT_TRUE(a != std::string::npos && b != std::string::npos && a < b) << doc_path;
  const std::string text =
      committed->substr(0, a + begin.size()) + table(all_rows(), cells) + committed->substr(b);
  ASSERT_TRUE(io::write_file_atomically(doc_path, text).ok());
  std::printf("[matrix] %s: row \"%s\" rewritten\n", doc_path.c_str(), row.name.c_str());
}

// One test per row of the matrix (CTest runs them side by side): its cell in every phase ends
// safe and its outcome is the one docs/reliability.md gives.
class FaultMatrix : public ::testing::TestWithParam<std::size_t> {};

TEST_P(FaultMatrix, EveryPhaseEndsSafeAndMatchesDocsReliability) {
  (void)log_capture();
  const FaultRow& row = all_rows()[GetParam()];
  const char* only = std::getenv("CDPR_MATRIX_ONLY");
  if (only != nullptr && row.name.find(only) == std::string::npos) GTEST_SKIP() << row.name;
  std::map<Phase, std::string> got;
  const auto wall0 = std::chrono::steady_clock::now();
  for (Phase p : kPhases) {
    std::string out;
    if (auto na = row.not_applicable.find(p); na != row.not_applicable.end()) {
      out = na->second;
    } else {
      const auto t0 = std::chrono::steady_clock::now();
      if (row.custom) {
        out = row.custom(p);
      } else {
        MatrixCell cell(row, p);
        out = cell.run();
      }
      std::printf("[matrix] %-45s | %-22s | %5.1f s | %s\n", row.name.c_str(), phase_name(p),
                  std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(),
                  out.c_str());
      std::fflush(stdout);
    }
    EXPECT_EQ(out.find("UNSAFE"), std::string::npos) << row.name << " / " << phase_name(p);
    got[p] = out;
  }
  std::printf("[matrix] %s: %zu cells in %.0f s wall\n", row.name.c_str(), got.size(),
              std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count());
  if (only != nullptr) return;
  if (std::getenv("CDPR_UPDATE_RELIABILITY") != nullptr) {
    rewrite_row(row, got);
    return;
  }
  const auto want = committed_cells();
  ASSERT_FALSE(want.empty()) << "docs/reliability.md is missing or has no generated table";
  for (const auto& [phase, text] : got) {
    auto it = want.find({row.name, phase});
    ASSERT_NE(it, want.end()) << "docs/reliability.md has no cell for " << row.name << " / "
                              << phase_name(phase);
    const auto allowed = alternatives(it->second);
    EXPECT_NE(std::find(allowed.begin(), allowed.end(), text), allowed.end())
        << "got: " << text << "\nwant: " << it->second << "\n"
        << "the outcome of " << row.name << " / " << phase_name(phase)
        << " differs from docs/reliability.md (CDPR_UPDATE_RELIABILITY=1 rewrites it after a "
           "deliberate change)";
  }
}

// The row's name as a test name: its letters and digits, each word capitalised.
std::string row_test_name(const ::testing::TestParamInfo<std::size_t>& info) {
  std::string name;
  bool word = true;
  for (const char c : all_rows()[info.param].name) {
    if (std::isalnum(static_cast<unsigned char>(c)) == 0) {
      word = true;
      continue;
    }
    name += word ? static_cast<char>(std::toupper(static_cast<unsigned char>(c))) : c;
    word = false;
  }
  return name;
}

INSTANTIATE_TEST_SUITE_P(Row, FaultMatrix, ::testing::Range<std::size_t>(0, all_rows().size()),
                         row_test_name);

// The committed table has the matrix's rows, in its order, each with a cell in every phase, and
// no other: a row taken out of the matrix leaves no stale row in docs/reliability.md.
TEST(FaultMatrixTable, DocsReliabilityHasEveryRowOfTheMatrixAndNoOther) {
  const auto want = committed_cells();
  ASSERT_FALSE(want.empty()) << "docs/reliability.md is missing or has no generated table";
  std::map<std::pair<std::string, Phase>, std::string> expected;
  for (const FaultRow& r : all_rows()) {
    for (Phase p : kPhases) {
      auto it = want.find({r.name, p});
      EXPECT_NE(it, want.end()) << "docs/reliability.md has no cell for " << r.name << " / "
                                << phase_name(p);
      if (it != want.end()) expected[it->first] = it->second;
    }
  }
  // The generated table of those cells is the committed one, row for row.
  auto committed = read_text_file(kSource + "/docs/reliability.md");
  ASSERT_TRUE(committed.ok());
  EXPECT_NE(committed->find("<!-- fault matrix: generated -->\n" + table(all_rows(), expected) +
                            "<!-- end of the generated fault matrix -->\n"),
            std::string::npos)
      << "docs/reliability.md's table has rows the matrix does not make, or another order";
}

}  // namespace
}  // namespace cdpr::controller
