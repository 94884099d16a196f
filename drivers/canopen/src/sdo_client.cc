#include "cdpr/canopen/sdo_client.hpp"

#include <algorithm>
#include <cstdio>

#include "cdpr/canopen/codes.hpp"

namespace cdpr::canopen {
namespace {

// Command specifier bytes (CiA 301, 7.2.4.3): client requests (ccs) and server answers (scs) in
// the top three bits of byte 0.
constexpr std::uint8_t kCcsDownloadSegment = 0x00;
constexpr std::uint8_t kCcsInitiateDownload = 0x20;
constexpr std::uint8_t kCcsInitiateUpload = 0x40;
constexpr std::uint8_t kCcsUploadSegment = 0x60;
constexpr std::uint8_t kAbort = 0x80;
constexpr std::uint8_t kScsUploadSegment = 0x00;
constexpr std::uint8_t kScsDownloadSegment = 0x20;
constexpr std::uint8_t kScsInitiateUpload = 0x40;
constexpr std::uint8_t kScsInitiateDownload = 0x60;
constexpr std::uint8_t kCsMask = 0xE0;
constexpr std::uint8_t kToggle = 0x10;

void put_mux(can::Frame& f, ObjectAddress a) {
  put_u16(&f.data[1], a.index);
  f.data[3] = a.sub;
}

}  // namespace

void BusPump::step() {
  can::Frame f;
  if (bus_.receive(f, receive_timeout_).ok()) {
    bool used = false;
    for (SdoClient* c : clients_) used = c->on_frame(f, clock_()) || used;
    if (!used && other_) other_(f);
  } else if (idle_) {
    idle_();
  }
}

SdoClient::SdoClient(can::CanBus& bus, NodeId node, SdoTiming timing)
    : bus_(bus), node_(node), timing_(timing) {
  buf_.reserve(kReserved);
}

Status SdoClient::start_upload(ObjectAddress a, Timestamp now) {
  if (busy()) {
    return Status::error(ErrorCode::kFailedPrecondition,
                         "node %u: SDO upload 0x%04X:%02X while another transfer runs",
                         unsigned{node_}, unsigned{a.index}, unsigned{a.sub});
  }
  op_ = Op::kUpload;
  addr_ = a;
  buf_.clear();
  return begin(now);
}

Status SdoClient::start_download(ObjectAddress a, std::span<const std::uint8_t> data,
                                 Timestamp now) {
  if (busy()) {
    return Status::error(ErrorCode::kFailedPrecondition,
                         "node %u: SDO download 0x%04X:%02X while another transfer runs",
                         unsigned{node_}, unsigned{a.index}, unsigned{a.sub});
  }
  if (data.empty()) {
    return Status::error(ErrorCode::kInvalidArgument,
                         "node %u: SDO download 0x%04X:%02X of 0 bytes", unsigned{node_},
                         unsigned{a.index}, unsigned{a.sub});
  }
  op_ = Op::kDownload;
  addr_ = a;
  buf_.assign(data.begin(), data.end());
  return begin(now);
}

// First attempt of a new transfer: sent now, or held back while the quiet period of an earlier
// abort runs (poll() sends it).
Status SdoClient::begin(Timestamp now) {
  last_now_ = now;
  attempt_ = 1;
  transfer_stale_ = 0;
  server_abort_ = 0;
  state_ = State::kBusy;
  result_ = Status::success();
  if (now < quiet_until_) {
    phase_ = Phase::kQuiet;
    deadline_ = quiet_until_;
    return Status::success();
  }
  deadline_ = now + timing_.timeout;
  return send_request();
}

// (Re)starts the transfer with its initiate request.
Status SdoClient::send_request() {
  phase_ = Phase::kInitiate;
  toggle_ = false;
  offset_ = 0;
  segments_ = 0;
  segment_answers_ = 0;
  last_segment_sent_ = false;
  expected_size_ = 0;
  size_unknown_ = false;
  can::Frame f = make_frame(cob::kSdoRx + node_, 8);
  put_mux(f, addr_);
  if (op_ == Op::kUpload) {
    buf_.clear();
    f.data[0] = kCcsInitiateUpload;
  } else if (buf_.size() <= 4) {
    // Expedited: e=1, s=1, n = 4 - size unused bytes.
    const auto n = static_cast<std::uint8_t>(4 - buf_.size());
    f.data[0] = static_cast<std::uint8_t>(kCcsInitiateDownload | (n << 2) | 0x03);
    std::copy(buf_.begin(), buf_.end(), f.data.begin() + 4);
  } else {
    // Segmented: e=0, s=1, size in bytes 4..7.
    f.data[0] = kCcsInitiateDownload | 0x01;
    put_u32(&f.data[4], static_cast<std::uint32_t>(buf_.size()));
  }
  Status s = bus_.send(f);
  if (!s.ok()) {
    fail(Status::error(ErrorCode::kIoError, "node %u: SDO %s 0x%04X:%02X: cannot send: %.*s",
                       unsigned{node_}, op_name(), unsigned{addr_.index}, unsigned{addr_.sub},
                       static_cast<int>(s.message().size()), s.message().data()));
    return result_;
  }
  return Status::success();
}

Status SdoClient::send_segment() {
  can::Frame f = make_frame(cob::kSdoRx + node_, 8);
  if (op_ == Op::kUpload) {
    f.data[0] = static_cast<std::uint8_t>(kCcsUploadSegment | (toggle_ ? kToggle : 0));
  } else {
    const std::size_t k = std::min<std::size_t>(7, buf_.size() - offset_);
    last_segment_sent_ = offset_ + k == buf_.size();
    f.data[0] = static_cast<std::uint8_t>(kCcsDownloadSegment | (toggle_ ? kToggle : 0) |
                                          ((7 - k) << 1) | (last_segment_sent_ ? 1 : 0));
    std::copy_n(buf_.begin() + static_cast<std::ptrdiff_t>(offset_), k, f.data.begin() + 1);
    offset_ += k;
  }
  ++segments_;
  return bus_.send(f);
}

void SdoClient::send_abort(std::uint32_t code, Timestamp now) {
  can::Frame f = make_frame(cob::kSdoRx + node_, 8);
  f.data[0] = kAbort;
  put_mux(f, addr_);
  put_u32(&f.data[4], code);
  (void)bus_.send(f);  // best effort: the transfer fails either way
  // The server may still answer the aborted request (or answer the abort): drain that first.
  quiet_until_ = now + timing_.quiet;
  abort_sent_ = code;
}

bool SdoClient::discard(const can::Frame& f) {
  ++stale_answers_;
  ++transfer_stale_;
  last_stale_cmd_ = f.dlc > 0 ? f.data[0] : 0;
  last_stale_mux_ = f.dlc >= 4 ? ObjectAddress{get_u16(&f.data[1]), f.data[3]} : ObjectAddress{};
  return true;
}

void SdoClient::fail(Status s) {
  state_ = State::kFailed;
  result_ = std::move(s);
}

void SdoClient::finish() {
  state_ = State::kDone;
  result_ = Status::success();
  if (op_ == Op::kDownload && download_observer_) download_observer_(addr_, buf_);
}

void SdoClient::cancel() {
  cancel(last_now_);
}

void SdoClient::cancel(Timestamp now) {
  if (!busy()) return;
  last_now_ = now;
  // Nothing was sent yet while the initiate is held back: no abort needed.
  if (phase_ != Phase::kQuiet) send_abort(abort_code::kGeneral, now);
  fail(Status::error(ErrorCode::kAborted, "node %u: SDO %s 0x%04X:%02X cancelled by the master",
                     unsigned{node_}, op_name(), unsigned{addr_.index}, unsigned{addr_.sub}));
}

void SdoClient::retry_or_fail(Timestamp now, const char* why) {
  // why == nullptr means the server did not answer in time.
  if (why == nullptr) send_abort(abort_code::kTimeout, now);
  if (attempt_ <= timing_.retries) {
    // The abort (above, or the toggle abort before) made the server drop its half-done transfer;
    // the new initiate waits for the quiet period so that late answers are drained first.
    ++attempt_;
    if (now < quiet_until_) {
      phase_ = Phase::kQuiet;
      deadline_ = quiet_until_;
      return;
    }
    deadline_ = now + timing_.timeout;
    (void)send_request();
    return;
  }
  if (why == nullptr) {
    if (transfer_stale_ == 0) {
      fail(Status::error(
          ErrorCode::kTimeout,
          "node %u: SDO %s 0x%04X:%02X timed out: no answer in %.0f ms (%d attempt%s)",
          unsigned{node_}, op_name(), unsigned{addr_.index}, unsigned{addr_.sub},
          to_ms(timing_.timeout), attempt_, attempt_ == 1 ? "" : "s"));
    } else {
      fail(Status::error(ErrorCode::kTimeout,
                         "node %u: SDO %s 0x%04X:%02X timed out: no answer in %.0f ms (%d "
                         "attempt%s; %u stale answer%s discarded, last command byte 0x%02X for "
                         "0x%04X:%02X)",
                         unsigned{node_}, op_name(), unsigned{addr_.index}, unsigned{addr_.sub},
                         to_ms(timing_.timeout), attempt_, attempt_ == 1 ? "" : "s",
                         unsigned{transfer_stale_}, transfer_stale_ == 1 ? "" : "s",
                         unsigned{last_stale_cmd_}, unsigned{last_stale_mux_.index},
                         unsigned{last_stale_mux_.sub}));
    }
  } else {
    fail(Status::error(ErrorCode::kProtocolError, "node %u: SDO %s 0x%04X:%02X: %s (%d attempt%s)",
                       unsigned{node_}, op_name(), unsigned{addr_.index}, unsigned{addr_.sub}, why,
                       attempt_, attempt_ == 1 ? "" : "s"));
  }
}

void SdoClient::poll(Timestamp now) {
  last_now_ = now;
  if (!busy()) return;
  if (phase_ == Phase::kQuiet) {
    if (now >= quiet_until_) {
      deadline_ = now + timing_.timeout;
      (void)send_request();
    }
    return;
  }
  if (now >= deadline_) retry_or_fail(now, nullptr);
}

bool SdoClient::on_frame(const can::Frame& f, Timestamp now) {
  if (f.error || f.rtr || f.extended || f.id != cob::kSdoTx + node_) return false;
  last_now_ = now;
  // Late answer to a finished transfer, or anything while the quiet period drains the server.
  if (!busy() || phase_ == Phase::kQuiet) return discard(f);
  if (f.dlc < 8) {
    send_abort(abort_code::kCommandSpecifier, now);
    fail(Status::error(
        ErrorCode::kProtocolError, "node %u: SDO %s 0x%04X:%02X: answer with dlc %u (must be 8)",
        unsigned{node_}, op_name(), unsigned{addr_.index}, unsigned{addr_.sub}, unsigned{f.dlc}));
    return true;
  }
  const std::uint8_t cmd = f.data[0];
  const ObjectAddress mux{get_u16(&f.data[1]), f.data[3]};

  if (cmd == kAbort) {
    const std::uint32_t code = get_u32(&f.data[4]);
    // A server aborts an initiate naming its object. Until it answered anything after our last
    // abort, an abort with a mid-transfer reason or our own code is its echo of that abort or its
    // own timeout of the aborted transfer.
    const bool echo = abort_sent_ != 0 && (code == abort_sent_ || code == abort_code::kToggleBit ||
                                           code == abort_code::kTimeout);
    if (phase_ == Phase::kInitiate && (!(mux == addr_) || echo)) return discard(f);
    abort_sent_ = 0;
    server_abort_ = code;
    const std::string_view text = sdo_abort_text(code);
    fail(Status::error(ErrorCode::kAborted, "node %u: SDO %s 0x%04X:%02X aborted: 0x%08X %.*s",
                       unsigned{node_}, op_name(), unsigned{addr_.index}, unsigned{addr_.sub},
                       unsigned{code}, static_cast<int>(text.size()), text.data()));
    return true;
  }

  const std::uint8_t cs = cmd & kCsMask;
  const std::uint8_t initiate_answer =
      op_ == Op::kUpload ? kScsInitiateUpload : kScsInitiateDownload;
  if (phase_ == Phase::kInitiate) {
    // Only the initiate answer naming our object can answer the initiate we sent; a segment
    // answer or an answer for another object is late (an aborted attempt or an earlier transfer).
    if (cs != initiate_answer || !(mux == addr_)) return discard(f);
  } else if (cs == initiate_answer && segment_answers_ == 0) {
    // A second initiate answer before any segment answer: the first of the two was the late
    // answer to the aborted attempt. The server answers in order, so our segment request reaches
    // it after the retry's initiate and the transfer stays in step: drop this one.
    return discard(f);
  }

  // Answers come in order: after this one, nothing of an aborted transfer can follow.
  abort_sent_ = 0;
  deadline_ = now + timing_.timeout;
  auto protocol_error = [&](const char* what) {
    send_abort(abort_code::kCommandSpecifier, now);
    fail(Status::error(ErrorCode::kProtocolError,
                       "node %u: SDO %s 0x%04X:%02X: %s (command byte 0x%02X)", unsigned{node_},
                       op_name(), unsigned{addr_.index}, unsigned{addr_.sub}, what, unsigned{cmd}));
  };

  if (op_ == Op::kUpload) {
    if (phase_ == Phase::kInitiate) {
      const bool expedited = (cmd & 0x02) != 0;
      const bool size_indicated = (cmd & 0x01) != 0;
      if (expedited) {
        const std::size_t n = size_indicated ? 4u - ((cmd >> 2) & 0x03u) : 4u;
        size_unknown_ = !size_indicated;
        buf_.assign(f.data.begin() + 4, f.data.begin() + 4 + static_cast<std::ptrdiff_t>(n));
        finish();
        return true;
      }
      expected_size_ = size_indicated ? get_u32(&f.data[4]) : 0;
      size_unknown_ = !size_indicated;
      if (expected_size_ > kMaxUpload) {
        send_abort(abort_code::kOutOfMemory, now);
        fail(Status::error(ErrorCode::kProtocolError,
                           "node %u: SDO upload 0x%04X:%02X: server announced %zu bytes, more than "
                           "the %zu this client takes",
                           unsigned{node_}, unsigned{addr_.index}, unsigned{addr_.sub},
                           expected_size_, kMaxUpload));
        return true;
      }
      phase_ = Phase::kSegment;
      toggle_ = false;
      if (!send_segment().ok()) retry_or_fail(now, "could not send a segment request");
      return true;
    }
    if (cs != kScsUploadSegment) return protocol_error("unexpected answer to upload segment"), true;
    if (((cmd & kToggle) != 0) != toggle_) {
      send_abort(abort_code::kToggleBit, now);
      char why[64];
      std::snprintf(why, sizeof why, "toggle bit not alternated (segment %u)", unsigned{segments_});
      retry_or_fail(now, why);
      return true;
    }
    ++segment_answers_;
    const std::size_t n = 7u - ((cmd >> 1) & 0x07u);
    if (buf_.size() + n > kMaxUpload) {
      send_abort(abort_code::kOutOfMemory, now);
      fail(Status::error(ErrorCode::kProtocolError,
                         "node %u: SDO upload 0x%04X:%02X: more than %zu bytes without a last "
                         "segment",
                         unsigned{node_}, unsigned{addr_.index}, unsigned{addr_.sub}, kMaxUpload));
      return true;
    }
    buf_.insert(buf_.end(), f.data.begin() + 1,
                f.data.begin() + 1 + static_cast<std::ptrdiff_t>(n));
    if (cmd & 0x01) {
      if (expected_size_ != 0 && buf_.size() != expected_size_) {
        fail(Status::error(ErrorCode::kProtocolError,
                           "node %u: SDO upload 0x%04X:%02X: got %zu bytes, server announced %zu",
                           unsigned{node_}, unsigned{addr_.index}, unsigned{addr_.sub}, buf_.size(),
                           expected_size_));
        return true;
      }
      finish();
      return true;
    }
    if (expected_size_ != 0 && buf_.size() > expected_size_) {
      send_abort(abort_code::kGeneral, now);
      fail(Status::error(ErrorCode::kProtocolError,
                         "node %u: SDO upload 0x%04X:%02X: %zu bytes and no last segment, "
                         "server announced %zu",
                         unsigned{node_}, unsigned{addr_.index}, unsigned{addr_.sub}, buf_.size(),
                         expected_size_));
      return true;
    }
    toggle_ = !toggle_;
    if (!send_segment().ok()) retry_or_fail(now, "could not send a segment request");
    return true;
  }

  // Download.
  if (phase_ == Phase::kInitiate) {
    if (buf_.size() <= 4) {
      finish();
      return true;
    }
    phase_ = Phase::kSegment;
    toggle_ = false;
    if (!send_segment().ok()) retry_or_fail(now, "could not send a segment");
    return true;
  }
  if (cs != kScsDownloadSegment)
    return protocol_error("unexpected answer to download segment"), true;
  if (((cmd & kToggle) != 0) != toggle_) {
    send_abort(abort_code::kToggleBit, now);
    char why[64];
    std::snprintf(why, sizeof why, "toggle bit not alternated (segment %u)", unsigned{segments_});
    retry_or_fail(now, why);
    return true;
  }
  ++segment_answers_;
  if (last_segment_sent_) {
    finish();
    return true;
  }
  toggle_ = !toggle_;
  if (!send_segment().ok()) retry_or_fail(now, "could not send a segment");
  return true;
}

Status SdoClient::wait(Pump& pump) {
  while (busy()) {
    pump.step();
    poll(pump.now());
  }
  return result_;
}

Status SdoClient::run_upload(ObjectAddress a, Pump& pump) {
  CDPR_RETURN_IF_ERROR(start_upload(a, pump.now()));
  return wait(pump);
}

Result<std::vector<std::uint8_t>> SdoClient::upload(ObjectAddress a, Pump& pump) {
  CDPR_RETURN_IF_ERROR(run_upload(a, pump));
  return std::vector<std::uint8_t>(buf_.begin(), buf_.end());
}

Status SdoClient::download(ObjectAddress a, std::span<const std::uint8_t> data, Pump& pump) {
  CDPR_RETURN_IF_ERROR(start_download(a, data, pump.now()));
  return wait(pump);
}

Result<std::string> SdoClient::read_string(ObjectAddress a, Pump& pump) {
  CDPR_RETURN_IF_ERROR(run_upload(a, pump));
  std::string out(buf_.begin(), buf_.end());
  // VISIBLE_STRING may be NUL-padded by the device.
  while (!out.empty() && out.back() == '\0') out.pop_back();
  return out;
}

Status SdoClient::write_string(ObjectAddress a, std::string_view s, Pump& pump) {
  return download(
      a, std::span<const std::uint8_t>(reinterpret_cast<const std::uint8_t*>(s.data()), s.size()),
      pump);
}

}  // namespace cdpr::canopen
