// The GoogleTest fixture of the in-process daemon tests (tests/daemon/*_test.cc): a VirtualCell
// (virtual_cell.hpp) in a fresh scratch folder per test, named after the test; the cell is
// destroyed and the folder removed after the test. The daemon is not started: each suite starts
// it with its own settings.
#pragma once

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <utility>

#include "virtual_cell.hpp"

namespace cdpr::controller::testing {

class CellTest : public ::testing::Test {
 protected:
  // `prefix` starts the scratch folder's name (then the pid and the test's name); `home`: the
  // tensions the virtual robot is homed with (VirtualCell::HomeTensions).
  explicit CellTest(std::string prefix,
                    VirtualCell::HomeTensions home = VirtualCell::HomeTensions::kPlanner)
      : prefix_(std::move(prefix)), home_(home) {}

  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           (prefix_ + std::to_string(::getpid()) + "-" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::remove_all(dir_);
    std::filesystem::create_directories(dir_);
    auto c = VirtualCell::create(CDPR_SOURCE_DIR, dir_, 7, VirtualCell::LaserLink::kTcp, home_);
    ASSERT_TRUE(c.ok()) << c.status().to_string();
    cell_ = std::move(*c);
  }
  void TearDown() override {
    cell_.reset();
    std::filesystem::remove_all(dir_);
  }

  void start_daemon(const VirtualCell::Settings& settings = {}) {
    const Status s = cell_->start_daemon(settings);
    ASSERT_TRUE(s.ok()) << s.to_string();
  }
  Daemon& daemon() { return *cell_->daemon; }
  bool run_until(const std::function<bool()>& done, double max_s) {
    return cell_->run_until(done, max_s);
  }
  Reply request(const std::string& cmd, const nlohmann::json& args = nlohmann::json::object()) {
    return cell_->request(cmd, args);
  }
  // Holding, the RT loop holding and settled, within `max_s` of robot time.
  bool holds_settled(double max_s) {
    return cell_->run_until(
        [&] {
          const RtSnapshot s = daemon().rt().snapshot();
          return daemon().state() == DaemonState::kHolding && s.mode == RtMode::kHolding &&
                 s.settled;
        },
        max_s);
  }

  std::filesystem::path dir_;
  std::unique_ptr<VirtualCell> cell_;

 private:
  std::string prefix_;
  VirtualCell::HomeTensions home_;
};

}  // namespace cdpr::controller::testing
