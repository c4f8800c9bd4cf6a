// A PBS node's priority order ("lower below higher" edges) kept as its transitive closure, so
// that "is h above a?" is one bit test and an agent's reservations are one row scan.
//
// Sparse and shared: a bit row (bit h set when h is above the agent, directly or through other
// agents) only for an agent that has someone above it, each row a block of a RowArena that the
// search's nodes share for the length of one planning call. A child starts with its parent's
// rows (an index per agent) and a row that an edge changes gets a new block, so a copy of a node
// costs an index per agent, not its closure. row_of[a] is a's block or -1; row_owner lists the
// agents that have a row, in the order they got one.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace rhcr {

// The rows of one planning call: `words` 64-bit words each, only ever appended.
class RowArena {
 public:
  void reset(int n_agents) {
    words_ = (n_agents + 63) / 64;
    bits_.clear();
  }
  int words() const { return words_; }
  // A new block, a copy of block `from` (or zeros for -1): its index.
  int add(int from) {
    const int b = static_cast<int>(bits_.size() / words_);
    bits_.resize(bits_.size() + words_, 0);
    if (from >= 0) std::copy_n(bits_.begin() + static_cast<ptrdiff_t>(from) * words_, words_, row(b));
    return b;
  }
  uint64_t* row(int b) { return bits_.data() + static_cast<size_t>(b) * words_; }
  const uint64_t* row(int b) const { return bits_.data() + static_cast<size_t>(b) * words_; }

 private:
  int words_ = 1;
  std::vector<uint64_t> bits_;
};

class PriorityOrder {
 public:
  // No edges among n agents, rows in `arena`.
  void reset(int n, RowArena& arena) {
    arena_ = &arena;
    row_of_.assign(n, -1);
    row_owner_.clear();
  }

  // A copy of `other` (its rows shared), reusing this one's buffers.
  void copy_from(const PriorityOrder& other) {
    arena_ = other.arena_;
    row_of_ = other.row_of_;
    row_owner_ = other.row_owner_;
  }

  // Bytes held (the rows are the arena's).
  size_t bytes() const { return (row_of_.capacity() + row_owner_.capacity()) * sizeof(int); }

  // Is `higher` above `lower`?
  bool is_above(int lower, int higher) const {
    const int r = row_of_[lower];
    return r >= 0 && ((arena_->row(r)[higher >> 6] >> (higher & 63)) & 1u);
  }

  // Calls f(h) for every agent h above `agent`, in increasing h.
  template <class F>
  void for_each_above(int agent, F&& f) const {
    const int r = row_of_[agent];
    if (r < 0) return;
    const uint64_t* above = arena_->row(r);
    for (int w = 0; w < arena_->words(); ++w)
      for (uint64_t bits = above[w]; bits; bits &= bits - 1) f(w * 64 + __builtin_ctzll(bits));
  }

  // Add "lower below higher" and keep the closure: whoever is `lower` or below it is now also
  // below `higher` and everything above `higher`. `scratch` is a caller's buffer.
  void add_edge(int lower, int higher, std::vector<uint64_t>& scratch) {
    RowArena& arena = *arena_;
    const int words = arena.words();
    const int rh = row_of_[higher];
    if (rh >= 0)
      scratch.assign(arena.row(rh), arena.row(rh) + words);
    else
      scratch.assign(words, 0);
    scratch[higher >> 6] |= uint64_t{1} << (higher & 63);
    auto merge = [&](int x) {  // x's row, copied on write, gets scratch's bits
      const int b = arena.add(row_of_[x]);
      row_of_[x] = b;
      uint64_t* r = arena.row(b);
      for (int w = 0; w < words; ++w) r[w] |= scratch[w];
    };
    for (int x : row_owner_)
      if (x != lower && is_above(x, lower)) merge(x);
    if (row_of_[lower] < 0) row_owner_.push_back(lower);
    merge(lower);
  }

 private:
  RowArena* arena_ = nullptr;
  std::vector<int> row_of_;
  std::vector<int> row_owner_;
};

}  // namespace rhcr
