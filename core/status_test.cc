#include "cdpr/status.hpp"

#include <gtest/gtest.h>

#include <memory>
#include <string>
#include <type_traits>
#include <vector>

namespace cdpr {
namespace {

TEST(Status, DefaultIsOkAndEmpty) {
  const Status s;
  EXPECT_TRUE(s.ok());
  EXPECT_EQ(s.to_string(), "ok");
}

TEST(Status, ErrorFormatsCodeAndMessage) {
  const Status s = Status::error(ErrorCode::kTimeout, "node %d: no answer in %d ms", 3, 100);
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

// Issue 16 item 6: a long message keeps the start (file, field) and the end of its reason.
TEST(Status, ErrorLongerThanTheBufferKeepsBothEndsOfTheMessage) {
  const std::string path = "/data/" + std::string(300, 'p') + "/samepose.csv";
  const std::string directions(600, 'd');
  const Status s = Status::error(ErrorCode::kFailedPrecondition,
                                 "%s: unidentifiable parameter choice: %s and a_6.", path.c_str(),
                                 directions.c_str());
  const std::string_view m = s.message();
  EXPECT_EQ(m.size(), Status::kMaxMessage - 1);
  EXPECT_EQ(m.substr(0, 12), "/data/pppppp");
  EXPECT_NE(m.find("..."), std::string_view::npos);
  EXPECT_EQ(m.substr(m.size() - 9), " and a_6.") << m;
}

TEST(Status, PrependToAFullMessageKeepsTheContextFileAndTheEndOfTheReason) {
  const std::string reason =
      "unidentifiable parameter choice: " + std::string(600, 'd') + " and a_6.";
  Status s(ErrorCode::kFailedPrecondition, reason);
  const std::string context = "calibrating config/mini.yaml from /tmp/check/samepose.csv: ";
  s.prepend(context);
  const std::string_view m = s.message();
  EXPECT_EQ(m.size(), Status::kMaxMessage - 1);
  EXPECT_EQ(m.substr(0, context.size()), context);
  EXPECT_NE(m.find("samepose.csv: unidentifiable parameter choice: "), std::string_view::npos) << m;
  EXPECT_EQ(m.substr(m.size() - 9), " and a_6.") << m;
}

// Status travels through the RT loop: copying it must stay a plain memory copy.
static_assert(std::is_trivially_copyable_v<Status>);

TEST(Result, CarriesValueOrStatus) {
  const Result<int> good(7);
  ASSERT_TRUE(good.ok());
  EXPECT_EQ(*good, 7);
  const Result<int> bad(Status(ErrorCode::kNotFound, "vcan9: no such CAN interface"));
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().code(), ErrorCode::kNotFound);
}

TEST(Result, OkStatusWithoutValueBecomesInternalError) {
  const Result<int> r{Status::success()};
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), ErrorCode::kInternal);
}

// Helpers for the propagation macros: each step records that it ran.
Status step(std::vector<int>& ran, int id, bool ok) {
  ran.push_back(id);
  return ok ? Status::success() : Status::error(ErrorCode::kTimeout, "step %d failed", id);
}

Result<int> value(std::vector<int>& ran, int id, bool ok) {
  ran.push_back(id);
  if (!ok) return Status::error(ErrorCode::kNotFound, "value %d missing", id);
  return 10 * id;
}

Status two_steps(std::vector<int>& ran, bool first_ok) {
  CDPR_RETURN_IF_ERROR(step(ran, 1, first_ok));
  CDPR_RETURN_IF_ERROR(step(ran, 2, true));
  return Status::success();
}

TEST(StatusMacros, ReturnIfErrorStopsAtTheFirstError) {
  std::vector<int> ran;
  const Status s = two_steps(ran, false);
  EXPECT_EQ(s.to_string(), "timeout: step 1 failed");
  EXPECT_EQ(ran, std::vector<int>{1});
  ran.clear();
  EXPECT_TRUE(two_steps(ran, true).ok());
  EXPECT_EQ(ran, (std::vector<int>{1, 2}));
}

Result<int> sum(std::vector<int>& ran, bool second_ok) {
  CDPR_ASSIGN_OR_RETURN(const int a, value(ran, 1, true));  // a declaration
  int b = 0;
  CDPR_ASSIGN_OR_RETURN(b, value(ran, 2, second_ok));  // an existing lvalue
  CDPR_RETURN_IF_ERROR(step(ran, 3, true));            // a Status inside a Result<T> function
  return a + b;
}

TEST(StatusMacros, AssignOrReturnDeclaresOrAssignsAndPassesTheStatusOn) {
  std::vector<int> ran;
  const Result<int> good = sum(ran, true);
  ASSERT_TRUE(good.ok()) << good.status().to_string();
  EXPECT_EQ(*good, 30);
  EXPECT_EQ(ran, (std::vector<int>{1, 2, 3}));
  ran.clear();
  const Result<int> bad = sum(ran, false);
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().to_string(), "not found: value 2 missing");
  EXPECT_EQ(ran, (std::vector<int>{1, 2}));
}

Status move_only(std::unique_ptr<int>& out) {
  CDPR_ASSIGN_OR_RETURN(out, Result<std::unique_ptr<int>>(std::make_unique<int>(5)));
  return Status::success();
}

TEST(StatusMacros, AssignOrReturnMovesTheValue) {
  std::unique_ptr<int> p;
  ASSERT_TRUE(move_only(p).ok());
  ASSERT_NE(p, nullptr);
  EXPECT_EQ(*p, 5);
}

}  // namespace
}  // namespace cdpr
