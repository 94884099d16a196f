#include "cdpr/canopen/config.hpp"

#include <gtest/gtest.h>

namespace cdpr::canopen {
namespace {

using namespace std::chrono_literals;

TEST(Config, LoadsTheMiniExample) {
  auto c = load_config(CDPR_SOURCE_DIR "/config/canopen-mini.yaml");
  ASSERT_TRUE(c.ok()) << c.status().to_string();
  EXPECT_EQ(c->sync_period, 4ms);
  EXPECT_EQ(c->heartbeat_cob_id(), 0x77Fu);
  ASSERT_EQ(c->nodes.size(), 9u);
  for (int i = 0; i < 8; ++i) {
    const NodeConfig& n = c->nodes[static_cast<std::size_t>(i)];
    EXPECT_EQ(n.id, i + 1);
    EXPECT_EQ(n.kind, NodeKind::kCia402Drive);
    ASSERT_EQ(n.rpdos.size(), 1u);
    EXPECT_EQ(n.rpdos[0].entries[1].object, (ObjectAddress{0x607A, 0}));
    EXPECT_EQ(n.rpdos[0].entries[1].type, DataType::kI32);
    EXPECT_EQ(n.master_heartbeat_timeout, 150ms);
    EXPECT_EQ(n.drive.abort_connection_option, 3);
  }
  EXPECT_EQ(c->sdo_quiet, 50ms);  // default
  auto q = parse_config("master:\n  sdo_quiet_ms: 20\nnodes:\n  - id: 1\n", "q.yaml");
  ASSERT_TRUE(q.ok()) << q.status().to_string();
  EXPECT_EQ(q->sdo_quiet, 20ms);
  const NodeConfig& f = c->nodes[8];
  EXPECT_EQ(f.kind, NodeKind::kForceSensor);
  ASSERT_EQ(f.force.gain.size(), 8u);  // a scalar gain expands to every channel
  EXPECT_EQ(f.force.gain[7], 2.0);
}

TEST(Config, ErrorsNameFileLineAndField) {
  const char* yaml =
      "master:\n"
      "  sync_period_ms: 4\n"
      "nodes:\n"
      "  - id: 1\n"
      "  - id: 300\n";
  auto c = parse_config(yaml, "net.yaml");
  ASSERT_FALSE(c.ok());
  EXPECT_EQ(std::string(c.status().message()), "net.yaml:5: nodes[1].id: 300 is outside 1..127");

  auto bad_map = parse_config(
      "nodes:\n  - id: 2\n    rpdo:\n      - number: 1\n        map: [\"0x6040 u16\"]\n", "x.yaml");
  ASSERT_FALSE(bad_map.ok());
  EXPECT_NE(bad_map.status().message().find("x.yaml:5: nodes[0].rpdo[0].map[0]: object '0x6040'"),
            std::string::npos)
      << bad_map.status().message();

  // Bad hex digits in the index or the sub-index (the parser checks where strtoul stopped).
  for (const char* obj : {"0x60ZZ:00", "0x6040:0G"}) {
    auto bad_hex = parse_config(std::string("nodes:\n  - id: 2\n    rpdo:\n      - number: 1\n"
                                            "        map: [\"") +
                                    obj + " u16\"]\n",
                                "h.yaml");
    ASSERT_FALSE(bad_hex.ok()) << obj;
    EXPECT_NE(bad_hex.status().message().find("is not INDEX:SUB in hexadecimal"), std::string::npos)
        << bad_hex.status().message();
  }

  auto typo = parse_config("master:\n  sync_periode_ms: 4\nnodes:\n  - id: 1\n", "t.yaml");
  ASSERT_FALSE(typo.ok());
  EXPECT_EQ(
      std::string(typo.status().message())
          .rfind("t.yaml:2: master.sync_periode_ms: unknown field (known fields: interface, ", 0),
      0u)
      << typo.status().message();

  auto drive = parse_config("nodes:\n  - id: 3\n    kind: cia402\n", "d.yaml");
  ASSERT_FALSE(drive.ok());
  EXPECT_EQ(std::string(drive.status().message()),
            "d.yaml: node 3 (node3): a cia402 drive needs 0x6041:00 in its TPDOs");
}

}  // namespace
}  // namespace cdpr::canopen
