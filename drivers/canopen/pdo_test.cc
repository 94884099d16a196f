#include "cdpr/canopen/pdo.hpp"

#include <gtest/gtest.h>

#include "cdpr/canopen/sdo_client.hpp"
#include "testing/sim_network.hpp"

namespace cdpr::canopen {
namespace {

using namespace std::chrono_literals;

PdoConfig drive_tpdo() {
  PdoConfig p;
  p.direction = PdoDirection::kTpdo;
  p.number = 1;
  p.entries = {{{0x6041, 0}, DataType::kU16}, {{0x6064, 0}, DataType::kI32}};
  return p;
}

TEST(Pdo, CompilesToOffsetsAndRoundTripsSignedValues) {
  PdoConfig p = drive_tpdo();
  EXPECT_EQ(p.entries[1].mapping_value(), 0x60640020u);
  EXPECT_EQ(p.comm_index(), 0x1800);
  EXPECT_EQ(p.mapping_index(), 0x1A00);
  ProcessImage img;
  auto l = PdoLayout::compile(p, 4, img);
  ASSERT_TRUE(l.ok());
  EXPECT_EQ(l->cob_id(), 0x184u);
  EXPECT_EQ(l->dlc(), 6);
  ASSERT_EQ(l->fields().size(), 2u);
  EXPECT_EQ(l->fields()[1].offset, 2);
  can::Frame f = make_frame(0x184, 6);
  f.data = {0x37, 0x02, 0xFE, 0xFF, 0xFF, 0xFF, 0, 0};
  ASSERT_TRUE(l->decode(f, img));
  EXPECT_EQ(img.get(static_cast<std::size_t>(img.find({0x6041, 0}))), 0x0237);
  EXPECT_EQ(img.get(static_cast<std::size_t>(img.find({0x6064, 0}))), -2);
  can::Frame out;
  l->encode(img, out);
  EXPECT_EQ(out.dlc, 6);
  EXPECT_EQ(out.data, f.data);
  f.dlc = 5;
  EXPECT_FALSE(l->decode(f, img));  // shorter than the mapping: not processed
}

TEST(Pdo, RejectsOversizedMappings) {
  PdoConfig p = drive_tpdo();
  p.entries.push_back({{0x606C, 0}, DataType::kI32});
  ProcessImage img;
  auto l = PdoLayout::compile(p, 4, img);
  ASSERT_FALSE(l.ok());
  EXPECT_EQ(std::string(l.status().message()),
            "node 4: TPDO1 maps 3 entries of 10 bytes (at most 8 bytes)");
}

TEST(Pdo, ConfiguresTheSlaveThroughSdoInTheRequiredOrder) {
  testing::SimNetwork net;
  auto& drive = net.add<slave::Drive402>(4);
  net.power_on();
  SdoClient sdo(net.master_bus(), 4, {50ms, 0});
  BusPump pump(
      net.master_bus(), [&] { return net.now(); }, 0ns);
  pump.add(sdo);
  pump.on_idle([&] { net.idle(); });
  PdoConfig p = drive_tpdo();
  p.transmission_type = 2;
  ASSERT_TRUE(configure_pdo(sdo, pump, p).ok());
  // Configuring again works: the PDO is disabled before its mapping changes.
  ASSERT_TRUE(configure_pdo(sdo, pump, p).ok());
  auto& od = drive.od();
  EXPECT_EQ(od.get({0x1800, 1}), 0x184);
  EXPECT_EQ(od.get({0x1800, 2}), 2);
  EXPECT_EQ(od.get({0x1A00, 0}), 2);
  EXPECT_EQ(od.get({0x1A00, 1}), 0x60410010);
  EXPECT_EQ(od.get({0x1A00, 2}), 0x60640020);
  // An object the device cannot map aborts with the reason.
  PdoConfig bad = p;
  bad.entries = {{{0x2FFF, 0}, DataType::kU16}};
  Status s = configure_pdo(sdo, pump, bad);
  EXPECT_EQ(std::string(s.message()),
            "node 4: SDO download 0x1A00:00 aborted: 0x06040041 object cannot be mapped to the "
            "PDO");
}

}  // namespace
}  // namespace cdpr::canopen
