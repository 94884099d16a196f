#include "cdpr/core/seqlock.hpp"

#include <gtest/gtest.h>

#include <array>
#include <atomic>
#include <chrono>
#include <thread>

namespace cdpr {
namespace {

struct Payload {
  std::array<std::uint64_t, 24> v{};  // every element equal in a consistent snapshot
};

TEST(SeqLock, StoresAndLoads) {
  SeqLock<Payload> s;
  EXPECT_EQ(s.version(), 1u);  // the initial value
  Payload p;
  p.v.fill(7);
  s.store(p);
  EXPECT_EQ(s.version(), 2u);
  EXPECT_EQ(s.load().v, p.v);
}

TEST(SeqLock, ReadersNeverSeeTornValues) {
  SeqLock<Payload> s;
  std::atomic<bool> done{false};
  std::atomic<long> torn{0};
  std::atomic<long> reads{0};
  std::thread reader([&] {
    while (!done.load(std::memory_order_relaxed)) {
      const Payload p = s.load();
      for (auto x : p.v) {
        if (x != p.v[0]) {
          torn.fetch_add(1);
          break;
        }
      }
      reads.fetch_add(1, std::memory_order_relaxed);
    }
  });
  // Write until the reader has overlapped many stores (bounded: 5 s on a loaded machine).
  Payload p;
  std::uint64_t i = 0;
  const auto t0 = std::chrono::steady_clock::now();
  while (i < 200000 || (reads.load() < 20000 &&
                        std::chrono::steady_clock::now() - t0 < std::chrono::seconds(5))) {
    p.v.fill(++i);
    s.store(p);
  }
  done = true;
  reader.join();
  EXPECT_EQ(torn.load(), 0);
  EXPECT_GT(reads.load(), 0);
  EXPECT_EQ(s.load().v[0], i);
}

}  // namespace
}  // namespace cdpr
