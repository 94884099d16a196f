// A single-writer sequence lock for a small trivially copyable value.
//
// The writer never waits; readers never block the writer and take no lock (they retry while a
// write is in progress). The payload is stored in relaxed atomic words, so concurrent access is
// not a data race; the sequence counter with acquire/release fences orders it. Suitable for the
// RT loop reading the newest sensor value published by a driver thread.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <cstring>
#include <type_traits>

namespace cdpr {

template <typename T>
class SeqLock {
  static_assert(std::is_trivially_copyable_v<T>, "SeqLock needs a trivially copyable type");
  static constexpr std::size_t kWords =
      (sizeof(T) + sizeof(std::uint64_t) - 1) / sizeof(std::uint64_t);

 public:
  SeqLock() { store(T{}); }
  explicit SeqLock(const T& initial) { store(initial); }

  // Single writer only.
  void store(const T& value) noexcept {
    std::array<std::uint64_t, kWords> buf{};
    std::memcpy(buf.data(), &value, sizeof(T));
    const std::uint64_t s = seq_.load(std::memory_order_relaxed);
    seq_.store(s + 1, std::memory_order_relaxed);  // odd: write in progress
    std::atomic_thread_fence(std::memory_order_release);
    for (std::size_t i = 0; i < kWords; ++i) words_[i].store(buf[i], std::memory_order_relaxed);
    seq_.store(s + 2, std::memory_order_release);
  }

  // Any number of readers. Copies a consistent snapshot; spins only while a store is running.
  T load() const noexcept {
    T out;
    while (!try_load(out)) {
    }
    return out;
  }

  // One attempt: false if a store ran concurrently (out is then unspecified).
  bool try_load(T& out) const noexcept {
    std::array<std::uint64_t, kWords> buf{};
    const std::uint64_t s1 = seq_.load(std::memory_order_acquire);
    if (s1 & 1u) return false;
    for (std::size_t i = 0; i < kWords; ++i) buf[i] = words_[i].load(std::memory_order_relaxed);
    std::atomic_thread_fence(std::memory_order_acquire);
    const std::uint64_t s2 = seq_.load(std::memory_order_relaxed);
    if (s1 != s2) return false;
    std::memcpy(static_cast<void*>(&out), buf.data(), sizeof(T));
    return true;
  }

  // Number of completed stores.
  std::uint64_t version() const noexcept { return seq_.load(std::memory_order_acquire) / 2; }

 private:
  std::atomic<std::uint64_t> seq_{0};
  std::array<std::atomic<std::uint64_t>, kWords> words_{};
};

}  // namespace cdpr
