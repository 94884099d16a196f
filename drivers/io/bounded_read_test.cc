// io::read_regular_file: what a client names is read only when it is a regular file of bounded
// size; devices and FIFOs are refused at once (issue 39: `--poses /dev/zero` read 23.7 GB, a FIFO
// hung past --timeout).
#include "cdpr/io/bounded_read.hpp"

#include <gtest/gtest.h>
#include <sys/stat.h>

#include <filesystem>
#include <fstream>
#include <string>

namespace cdpr::io {
namespace {

std::string scratch(const std::string& name) {
  const auto dir =
      std::filesystem::path(::testing::TempDir()) / ("bounded-read-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const auto p = dir / name;
  std::filesystem::remove(p);
  return p.string();
}

TEST(BoundedRead, ReadsARegularFileWithinTheLimit) {
  const std::string p = scratch("ok.csv");
  std::ofstream(p) << "x,y\n1,2\n";
  auto r = read_regular_file(p, 8);
  ASSERT_TRUE(r.ok()) << r.status().to_string();
  EXPECT_EQ(*r, "x,y\n1,2\n");
}

TEST(BoundedRead, RefusesAFileLargerThanTheLimitBeforeReadingIt) {
  const std::string p = scratch("big.csv");
  std::ofstream(p) << std::string(1001, 'a');
  auto r = read_regular_file(p, 1000);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), ErrorCode::kOutOfRange);
  EXPECT_EQ(std::string(r.status().message()),
            p + " is too large: 1001 bytes, more than the 1000 allowed");
}

TEST(BoundedRead, RefusesDevicesDirectoriesAndFifosWithoutBlocking) {
  auto zero = read_regular_file("/dev/zero", 1 << 20);
  ASSERT_FALSE(zero.ok());
  EXPECT_EQ(std::string(zero.status().message()),
            "/dev/zero is a character device, not a regular file");
  auto dir = read_regular_file("/", 1 << 20);
  ASSERT_FALSE(dir.ok());
  EXPECT_EQ(dir.status().code(), ErrorCode::kInvalidArgument);
  const std::string fifo = scratch("fifo");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  auto f = read_regular_file(fifo, 1 << 20);  // no writer: a blocking open would hang here
  ASSERT_FALSE(f.ok());
  EXPECT_EQ(std::string(f.status().message()), fifo + " is a FIFO, not a regular file");
  auto missing = read_regular_file(scratch("missing"), 10);
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.status().code(), ErrorCode::kNotFound);
}

}  // namespace
}  // namespace cdpr::io
