#include "cdpr/config/yaml_reader.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <string>

namespace cdpr::config {
namespace {

// The document `text` named "f.yaml"; the test fails when it does not parse.
YamlField root_of(const std::string& text) {
  Result<YamlDocument> doc = YamlDocument::parse(text, "f.yaml");
  EXPECT_TRUE(doc.ok()) << doc.status().to_string();
  return doc.ok() ? doc->root() : YamlDocument::parse("{}", "f.yaml")->root();
}

template <typename T>
std::string error_of(const Result<T>& r) {
  EXPECT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), ErrorCode::kInvalidArgument);
  return std::string(r.status().message());
}
std::string error_of(const Status& s) {
  EXPECT_FALSE(s.ok());
  EXPECT_EQ(s.code(), ErrorCode::kInvalidArgument);
  return std::string(s.message());
}

TEST(YamlReader, NumbersCarrySignAndUnitInTheMessage) {
  const YamlField r = root_of("a: -5\nb: heavy\nc: .nan\nd: 0x10\ne: 1.5e3\nf: [1]\n");
  EXPECT_EQ(error_of(r["a"].number(Sign::kPositive, "N")),
            "f.yaml:1: a: expected a positive number (N), got -5");
  EXPECT_EQ(error_of(r["b"].number(Sign::kNonNegative, "kg")),
            "f.yaml:2: b: expected a non-negative number (kg), got heavy");
  EXPECT_EQ(error_of(r["c"].number(Sign::kAny, "m")),
            "f.yaml:3: c: expected a finite number (m), got .nan");
  EXPECT_EQ(*r["d"].number(), 16.0);
  EXPECT_EQ(*r["e"].number(Sign::kPositive, "m"), 1500.0);
  EXPECT_EQ(error_of(r["f"].number(Sign::kNonZero, "")),
            "f.yaml:6: f: expected a non-zero number, got a list of 1");
  EXPECT_EQ(error_of(r["a"].number_in(0, 1000, "ms")),
            "f.yaml:1: a: expected a number within 0..1000 (ms), got -5");
}

TEST(YamlReader, IntegersAreDecimalOrHexWithinTheirRange) {
  const YamlField r = root_of("id: 300\nhex: 0x7FF\nneg: -128\nword: three\n");
  EXPECT_EQ(error_of(r["id"].integer(1, 127)), "f.yaml:1: id: 300 is outside 1..127");
  EXPECT_EQ(*r["hex"].integer(0, 0x7FF), 0x7FF);
  EXPECT_EQ(*r["neg"].integer(-128, 127), -128);
  EXPECT_EQ(error_of(r["word"].integer(0, 9)), "f.yaml:4: word: 'three' is not an integer");
}

TEST(YamlReader, MissingFieldsNameTheirPathAtTheEnclosingMapsLine) {
  const YamlField r = root_of("name: x\nvalue:\n  type: u16\n");
  EXPECT_EQ(error_of(r["value"].required("register", "the first register")),
            "f.yaml:3: value.register: missing (the first register)");
  EXPECT_EQ(error_of(r["value"]["scale"].number(Sign::kAny, "m")),
            "f.yaml:3: value.scale: missing (m)");
  EXPECT_EQ(error_of(r["value"]["type"].choice({"u32", "f32"})),
            "f.yaml:3: value.type: 'u16' is not one of u32, f32");
}

TEST(YamlReader, UnknownAndRepeatedKeysAreRefusedAtTheirOwnLine) {
  const YamlField r = root_of("master:\n  sync_periode_ms: 4\ncable:\n  ea: 1\n  ea: 2\n");
  EXPECT_EQ(error_of(r["master"].check_keys({"sync_period_ms", "bitrate"})),
            "f.yaml:2: master.sync_periode_ms: unknown field (known fields: sync_period_ms, "
            "bitrate)");
  EXPECT_EQ(error_of(r["cable"].check_keys({"ea"})), "f.yaml:5: cable.ea: field given twice");
  EXPECT_EQ(error_of(r.check_keys({"master"})),
            "f.yaml:3: cable: unknown field (known fields: master)");
  EXPECT_EQ(error_of(r["master"]["sync_periode_ms"].check_keys({})),
            "f.yaml:2: master.sync_periode_ms: expected a map, got 4");
}

TEST(YamlReader, OptionalFieldsKeepTheirDefaultWhenAbsentOrEmpty) {
  const YamlField r = root_of("rate: 50\nempty:\nflag: yes\nmode: pp\nbaud: 0x4B00\n");
  double rate = 1.0, empty = 2.0, absent = 3.0;
  ASSERT_TRUE(r.optional("rate", rate, Sign::kPositive, "Hz").ok());
  ASSERT_TRUE(r.optional("empty", empty).ok());
  ASSERT_TRUE(r.optional("absent", absent).ok());
  EXPECT_EQ(rate, 50.0);
  EXPECT_EQ(empty, 2.0);  // a key without a value counts as absent
  EXPECT_EQ(absent, 3.0);
  bool flag = false;
  ASSERT_TRUE(r.optional("flag", flag).ok());
  EXPECT_TRUE(flag);
  int mode = 0;
  ASSERT_TRUE(r.optional_choice("mode", mode, {"csp", "pp"}).ok());
  EXPECT_EQ(mode, 1);
  std::uint32_t baud = 0;
  ASSERT_TRUE(r.optional("baud", baud, 300, 4000000).ok());
  EXPECT_EQ(baud, 19200u);
  EXPECT_EQ(error_of(r.optional("rate", baud, 1, 10)), "f.yaml:1: rate: 50 is outside 1..10");
}

TEST(YamlReader, ListsVectorsBooleansAndTexts) {
  const YamlField r =
      root_of("v: [1, 2]\nw: [0, .inf, 1]\nl: [1, 2, 3]\nb: maybe\nt: {a: 1}\none: 4\n");
  EXPECT_EQ(error_of(r["v"].vector3("m")),
            "f.yaml:1: v: expected a list of 3 numbers (m), got a list of 2");
  EXPECT_EQ(error_of(r["w"].vector3("m")),
            "f.yaml:2: w[1]: expected a finite number (m), got .inf");
  EXPECT_EQ(r["l"].vector3("m")->at(2), 3.0);
  EXPECT_EQ(r["l"].size(), 3u);
  EXPECT_EQ(r["l"][std::size_t{1}].path(), "l[1]");
  EXPECT_EQ(error_of(r["b"].boolean()), "f.yaml:4: b: expected true or false, got maybe");
  EXPECT_EQ(error_of(r["t"].text()), "f.yaml:5: t: expected a text, got a map");
  EXPECT_EQ(r["one"].numbers(Sign::kAny, "N", true)->size(), 1u);
  EXPECT_EQ(error_of(r["one"].numbers(Sign::kAny, "N", false)),
            "f.yaml:6: one: expected a list of numbers (N), got 4");
}

TEST(YamlReader, SyntaxErrorsAndMissingFilesNameTheFile) {
  const Result<YamlDocument> bad = YamlDocument::parse("a: [1, 2\n", "bad.yaml");
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().code(), ErrorCode::kParseError);
  EXPECT_EQ(std::string(bad.status().message()).rfind("bad.yaml:2:", 0), 0u)
      << bad.status().message();
  EXPECT_NE(bad.status().message().find("YAML syntax error"), std::string_view::npos);
  const Result<YamlDocument> missing = YamlDocument::load("/nonexistent/x.yaml", "robot config");
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.status().code(), ErrorCode::kNotFound);
  EXPECT_EQ(std::string(missing.status().message())
                .rfind("cannot open robot config /nonexistent/x.yaml", 0),
            0u);
}

TEST(YamlReader, AssigningAFieldRebindsItAndLeavesTheDocumentAlone) {
  const YamlField r = root_of("a: 1\nb: 2\n");
  YamlField f = r["a"];
  f = r["b"];  // yaml-cpp would copy b's value into a on a plain node assignment
  EXPECT_EQ(*f.number(), 2.0);
  EXPECT_EQ(*r["a"].number(), 1.0);
  EXPECT_EQ(f.path(), "b");
}

}  // namespace
}  // namespace cdpr::config
