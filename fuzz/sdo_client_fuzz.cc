// The SDO client (canopen::SdoClient) fed arbitrary frames as the server's answers, interleaved
// with the passing of time, cancels and new transfers. It must never crash, take only frames of
// its own COB-ID, send only well-formed requests to its server, end every transfer that fails
// with a message, and (upload) deliver no more bytes than a finished transfer can carry.
//
// Input: a sequence of steps; the first byte of each step says what happens (see `switch`). A
// step may copy the running transfer's object into the frame (bytes 1..3), which lets the fuzzer
// get past the client's "answer names another object" check.
#include <fuzzer/FuzzedDataProvider.h>

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "cdpr/can/virtual_bus.hpp"
#include "cdpr/canopen/sdo_client.hpp"
#include "fuzz_util.hpp"

namespace can = cdpr::can;
namespace co = cdpr::canopen;
using namespace std::chrono_literals;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  FuzzedDataProvider in(data, size);
  cdpr::ManualClock clock;
  can::VirtualCanBus bus(clock);
  auto master = bus.endpoint("master");
  auto server = bus.endpoint("server");
  const co::NodeId node = in.ConsumeIntegralInRange<co::NodeId>(1, co::kMaxNodeId);
  co::SdoTiming timing;
  timing.timeout = 100ms;
  timing.quiet = 50ms;
  timing.retries = in.ConsumeIntegralInRange<int>(0, 3);
  co::SdoClient client(*master, node, timing);
  co::ObjectAddress addr{0x2000, 1};
  bool upload = true;
  std::size_t download_size = 0;

  auto start = [&](bool up, std::size_t n) {
    addr.index = in.ConsumeIntegral<std::uint16_t>();
    addr.sub = in.ConsumeIntegral<std::uint8_t>();
    upload = up;
    if (up) {
      (void)client.start_upload(addr, clock.now());
    } else {
      std::vector<std::uint8_t> bytes(n, 0x5A);
      download_size = n;
      (void)client.start_download(addr, bytes, clock.now());
    }
  };
  start(in.ConsumeBool(), in.ConsumeIntegralInRange<std::size_t>(1, 40));

  for (int steps = 0; steps < 4096 && in.remaining_bytes() > 0; ++steps) {
    const std::uint8_t op = in.ConsumeIntegral<std::uint8_t>();
    switch (op % 8) {
      case 0:
      case 1:
      case 2:
      case 3: {  // a frame from the server (or, rarely, from elsewhere)
        can::Frame f;
        f.id =
            (op & 0x80) ? in.ConsumeIntegral<std::uint16_t>() & can::kMaxStandardId : 0x580u + node;
        f.dlc = (op & 0x40) ? in.ConsumeIntegralInRange<std::uint8_t>(0, 8) : 8;
        f.rtr = (op & 0xC0) == 0xC0;
        for (auto& b : f.data) b = in.ConsumeIntegral<std::uint8_t>();
        if (op & 0x10) {
          f.data[1] = static_cast<std::uint8_t>(addr.index & 0xFF);
          f.data[2] = static_cast<std::uint8_t>(addr.index >> 8);
          f.data[3] = addr.sub;
        }
        const bool mine = !f.rtr && f.id == 0x580u + node;
        CDPR_FUZZ_CHECK(client.on_frame(f, clock.now()) == mine,
                        "takes exactly the frames of its COB-ID");
        break;
      }
      case 4:
        clock.advance(std::chrono::milliseconds(in.ConsumeIntegralInRange<int>(0, 200)));
        client.poll(clock.now());
        break;
      case 5:
        if (op & 0x08) {
          client.cancel(clock.now());
        } else {
          client.cancel();
        }
        CDPR_FUZZ_CHECK(!client.busy(), "a cancelled transfer is over");
        break;
      case 6:
        if (!client.busy()) start((op & 0x08) != 0, in.ConsumeIntegralInRange<std::size_t>(1, 40));
        break;
      case 7:
        clock.advance(std::chrono::milliseconds(1));
        client.poll(clock.now());
        break;
    }
    // Whatever the client sent: requests to its server only, well formed.
    can::Frame sent;
    while (server->receive(sent, 0ns).ok()) {
      CDPR_FUZZ_CHECK(sent.id == 0x600u + node && !sent.extended && !sent.rtr,
                      "requests go to the server's COB-ID");
      CDPR_FUZZ_CHECK(sent.dlc == 8, "SDO requests have 8 bytes");
    }
    CDPR_FUZZ_CHECK(client.data().size() <= co::SdoClient::kMaxUpload,
                    "an upload never holds more than the client's limit");
    if (client.state() == co::SdoClient::State::kFailed) {
      CDPR_FUZZ_CHECK(!client.result().ok() && !client.result().message().empty(),
                      "a failed transfer names its reason");
    }
    if (client.state() == co::SdoClient::State::kDone) {
      CDPR_FUZZ_CHECK(client.result().ok(), "a finished transfer is ok");
      if (upload) {
        CDPR_FUZZ_CHECK(client.data().size() <= 7u * 4096u, "no more bytes than segments carry");
      } else {
        CDPR_FUZZ_CHECK(client.data().size() == download_size, "download data is unchanged");
      }
    }
  }
  return 0;
}
