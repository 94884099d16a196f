// SDO client (CiA 301, 7.2.4): expedited and segmented upload and download with toggle-bit
// checking, per-request timeouts and whole-transfer retries.
//
// SDO frames carry no transaction number, so after a timeout the server's late answer to the
// aborted attempt can arrive while the retry runs. The client guards against pairing it with the
// wrong request: after it sent an abort it waits a quiet period (SdoTiming::quiet) before the next
// initiate and discards everything the server sends meanwhile; afterwards it discards (and counts,
// stale_answers()) every answer that cannot belong to the current attempt: an answer of the wrong
// kind or naming another object in the initiate phase, an abort of another object or with a
// mid-transfer code (toggle bit, timeout: the server's echo/answer to the aborted transfer) in the
// initiate phase until the server answered anything after our abort, a second initiate answer
// before the first segment answer (the server answers in order, so one of the two initiate answers
// was late and the segment request we sent after the first one reaches the server after the retry's
// initiate), and anything while idle. The server may answer our abort with nothing or with an
// abort; neither is waited for.
//
// The client is a state machine fed with frames and time (on_frame / poll), so the master can run
// one per node in parallel, or in its RT cycle for small transfers (the data buffer is reserved at
// construction: transfers up to kReserved bytes never allocate). The blocking helpers (upload,
// download, read<T>, write<T>, strings) drive it through a Pump, which receives frames and keeps
// time: a real clock on the robot, an injected one in tests. Blocking helpers are for start-up and
// maintenance only; they allocate.
#pragma once

#include <chrono>
#include <concepts>
#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <type_traits>
#include <vector>

#include "cdpr/can/can_bus.hpp"
#include "cdpr/canopen/types.hpp"
#include "cdpr/status.hpp"

namespace cdpr::canopen {

struct SdoTiming {
  std::chrono::nanoseconds timeout{std::chrono::milliseconds(100)};  // per request/answer
  int retries = 2;  // whole-transfer restarts after a timeout or a toggle error
  // After the client sent an abort: no new initiate and every answer discarded for this long, so
  // that late answers of the aborted transfer are drained before the retry (or next transfer).
  std::chrono::nanoseconds quiet{std::chrono::milliseconds(50)};
};

class SdoClient;

// Something that waits for traffic: receives what is there (at most a short wait), hands every
// frame to whoever needs it (SDO clients, NMT monitor, ...) and tells the time.
class Pump {
 public:
  virtual ~Pump() = default;
  virtual Timestamp now() = 0;
  virtual void step() = 0;
};

// A Pump for a bare bus: frames go to the registered clients, everything else to `other`.
class BusPump final : public Pump {
 public:
  using Clock = std::function<Timestamp()>;
  BusPump(can::CanBus& bus, Clock clock,
          std::chrono::nanoseconds receive_timeout = std::chrono::milliseconds(1))
      : bus_(bus), clock_(std::move(clock)), receive_timeout_(receive_timeout) {}
  void add(SdoClient& client) { clients_.push_back(&client); }
  // Called when no frame was waiting (tests step simulated peers and advance the clock here).
  void on_idle(std::function<void()> idle) { idle_ = std::move(idle); }
  void on_other(std::function<void(const can::Frame&)> other) { other_ = std::move(other); }
  Timestamp now() override { return clock_(); }
  void step() override;

 private:
  can::CanBus& bus_;
  Clock clock_;
  std::chrono::nanoseconds receive_timeout_;
  std::vector<SdoClient*> clients_;
  std::function<void()> idle_;
  std::function<void(const can::Frame&)> other_;
};

class SdoClient {
 public:
  static constexpr std::size_t kReserved = 1024;
  // The largest upload the client takes (announced or, without a size, received): a server that
  // announces more, or sends more segments than this without the last one, is aborted with
  // "out of memory" (0x05040005) and the transfer fails naming the size.
  static constexpr std::size_t kMaxUpload = 64 * 1024;
  enum class State { kIdle, kBusy, kDone, kFailed };

  SdoClient(can::CanBus& bus, NodeId node, SdoTiming timing = {});

  NodeId node() const { return node_; }
  void set_timing(SdoTiming t) { timing_ = t; }

  // Non-blocking interface. start_* sends the first request (fails if a transfer is running or
  // the frame cannot be queued). Data of a finished upload is in data().
  Status start_upload(ObjectAddress a, Timestamp now);
  Status start_download(ObjectAddress a, std::span<const std::uint8_t> data, Timestamp now);
  // Feeds one frame; returns true if it was addressed to this client (COB-ID 0x580 + node).
  bool on_frame(const can::Frame& frame, Timestamp now);
  // Handles timeouts: restarts the transfer while retries remain, then fails.
  void poll(Timestamp now);
  // Abandons a running transfer and tells the server (abort 0x08000000 general error).
  void cancel();
  void cancel(Timestamp now);

  State state() const { return state_; }
  bool busy() const { return state_ == State::kBusy; }
  const Status& result() const { return result_; }
  std::span<const std::uint8_t> data() const { return buf_; }
  int attempts() const { return attempt_; }
  // Answers discarded because they cannot belong to the running attempt (late answers to an
  // aborted attempt or an earlier transfer), since construction.
  std::uint64_t stale_answers() const { return stale_answers_; }
  // The abort code with which the server ended the last transfer (0: it did not abort it).
  std::uint32_t server_abort_code() const { return server_abort_; }
  // Called with the object and the data of every download the server confirmed (the master keeps
  // what it applied for the DCF). Empty: none. The call itself does not allocate.
  using DownloadObserver = std::function<void(ObjectAddress, std::span<const std::uint8_t>)>;
  void set_download_observer(DownloadObserver observer) {
    download_observer_ = std::move(observer);
  }

  // Blocking interface (start-up/maintenance). Errors name node, object and reason.
  Result<std::vector<std::uint8_t>> upload(ObjectAddress a, Pump& pump);
  Status download(ObjectAddress a, std::span<const std::uint8_t> data, Pump& pump);

  template <typename T>
  requires std::is_integral_v<T> &&(sizeof(T) <= 4) Result<T> read(ObjectAddress a, Pump& pump) {
    Status s = run_upload(a, pump);
    if (!s.ok()) return s;
    if (buf_.size() != sizeof(T) && !(size_unknown_ && buf_.size() >= sizeof(T))) {
      return Status::error(ErrorCode::kProtocolError,
                           "node %u: SDO upload 0x%04X:%02X returned %zu bytes, expected %zu",
                           unsigned{node_}, unsigned{a.index}, unsigned{a.sub}, buf_.size(),
                           sizeof(T));
    }
    using U = std::make_unsigned_t<T>;
    return static_cast<T>(static_cast<U>(get_le(buf_.data(), sizeof(T))));
  }

  template <typename T>
  requires std::is_integral_v<T> &&(sizeof(T) <= 4) Status
      write(ObjectAddress a, T value, Pump& pump) {
    std::uint8_t b[sizeof(T)];
    using U = std::make_unsigned_t<T>;
    put_le(b, static_cast<U>(value), sizeof(T));
    return download(a, std::span<const std::uint8_t>(b, sizeof(T)), pump);
  }

  Result<std::string> read_string(ObjectAddress a, Pump& pump);
  Status write_string(ObjectAddress a, std::string_view s, Pump& pump);

 private:
  enum class Op { kUpload, kDownload };
  // kQuiet: the initiate is held back until quiet_until_ (after an abort we sent).
  enum class Phase { kQuiet, kInitiate, kSegment };

  Status run_upload(ObjectAddress a, Pump& pump);
  Status wait(Pump& pump);
  Status begin(Timestamp now);
  Status send_request();
  Status send_segment();
  void send_abort(std::uint32_t code, Timestamp now);
  bool discard(const can::Frame& f);  // counts a stale answer; returns true (frame consumed)
  void fail(Status s);
  void retry_or_fail(Timestamp now, const char* why);
  void finish();
  const char* op_name() const { return op_ == Op::kUpload ? "upload" : "download"; }

  can::CanBus& bus_;
  NodeId node_;
  SdoTiming timing_;
  State state_ = State::kIdle;
  Op op_ = Op::kUpload;
  Phase phase_ = Phase::kInitiate;
  ObjectAddress addr_{};
  std::vector<std::uint8_t> buf_;  // upload: received data; download: data to send
  std::size_t offset_ = 0;         // download: bytes sent so far
  std::size_t expected_size_ = 0;  // upload: size announced by the server (0 = unknown)
  bool size_unknown_ = false;
  bool toggle_ = false;
  bool last_segment_sent_ = false;
  int attempt_ = 0;
  std::uint32_t segments_ = 0;
  std::uint32_t segment_answers_ = 0;  // segment answers taken in this attempt
  Timestamp deadline_{0};
  Timestamp quiet_until_{0};
  Timestamp last_now_{0};         // latest time seen (for cancel() without a time)
  std::uint32_t abort_sent_ = 0;  // code of our last abort until the server answered anything
  std::uint64_t stale_answers_ = 0;
  std::uint32_t server_abort_ = 0;
  DownloadObserver download_observer_;
  std::uint32_t transfer_stale_ = 0;  // stale answers during the running transfer
  std::uint8_t last_stale_cmd_ = 0;
  ObjectAddress last_stale_mux_{};
  Status result_;
};

}  // namespace cdpr::canopen
