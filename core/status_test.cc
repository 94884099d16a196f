#include "cdpr/status.hpp"

#include <gtest/gtest.h>

#include <string>

namespace cdpr {
namespace {

TEST(Status, DefaultIsOkAndEmpty) {
  const Status s;
  EXPECT_TRUE(s.ok());
  EXPECT_EQ(s.to_string(), "ok");
}

TEST(Status, ErrorFormatsCodeAndMessage) {
  const Status s = Status::Error(ErrorCode::kTimeout, "node %d: no answer in %d ms", 3, 100);
  EXPECT_FALSE(s.ok());
  EXPECT_EQ(s.code(), ErrorCode::kTimeout);
  EXPECT_EQ(s.to_string(), "timeout: node 3: no answer in 100 ms");
}

TEST(Status, PrependAddsContextInFront) {
  Status s(ErrorCode::kParseError, "cables[3].ea: expected a positive number");
  s.prepend("config/mini.yaml:42: ");
  EXPECT_EQ(s.message(), "config/mini.yaml:42: cables[3].ea: expected a positive number");
}

TEST(Status, LongMessagesAreTruncatedNotOverflowed) {
  Status s(ErrorCode::kIoError, std::string(1000, 'x'));
  EXPECT_EQ(s.message().size(), Status::kMaxMessage - 1);
  s.prepend("ctx: ");
  EXPECT_EQ(s.message().size(), Status::kMaxMessage - 1);
  EXPECT_EQ(s.message().substr(0, 5), "ctx: ");
}

TEST(Status, PrependShortensALongContextInTheMiddleAndKeepsTheReason) {
  const std::string reason =
      "cable count mismatch: the recording has 7 cables but config 'MINI' has 8";
  Status s(ErrorCode::kFailedPrecondition, reason);
  const std::string dir(2 * Status::kMaxMessage, 'd');
  s.prepend("/check/" + dir + "/seven-cables.csv vs /check/config/mini.yaml: ");
  const std::string_view m = s.message();
  EXPECT_EQ(m.size(), Status::kMaxMessage - 1);
  EXPECT_EQ(m.substr(0, 7), "/check/");
  EXPECT_NE(m.find("..."), std::string_view::npos);
  EXPECT_NE(m.find("mini.yaml: " + reason), std::string_view::npos) << m;
}

TEST(Result, CarriesValueOrStatus) {
  const Result<int> good(7);
  ASSERT_TRUE(good.ok());
  EXPECT_EQ(*good, 7);
  const Result<int> bad(Status(ErrorCode::kNotFound, "vcan9: no such CAN interface"));
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().code(), ErrorCode::kNotFound);
}

TEST(Result, OkStatusWithoutValueBecomesInternalError) {
  const Result<int> r{Status::Ok()};
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), ErrorCode::kInternal);
}

}  // namespace
}  // namespace cdpr
