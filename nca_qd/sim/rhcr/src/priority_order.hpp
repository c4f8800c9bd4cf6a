// A PBS node's priority order ("lower below higher" edges) kept as its transitive closure, so
// that "is h above a?" is one bit test and an agent's reservations are one row scan.
//
// Sparse both ways: a bit row only for an agent that has someone above it, a bit column only
// for an agent that is above someone (few of either in a typical node). row_of[a] is a's row
// in `rows` (`stride` 64-bit words each) or -1; col_of[h] is h's column (col_agent[c] the agent
// of column c) or -1. Bit col_of[h] of a's row is set when h is above a, directly or through
// other agents; row_owner lists the agents that have a row.
#pragma once

#include <algorithm>
#include <cstdint>
#include <vector>

namespace rhcr {

class PriorityOrder {
 public:
  // No edges among n agents.
  void reset(int n) {
    row_of_.assign(n, -1);
    col_of_.assign(n, -1);
    rows_.clear();
    row_owner_.clear();
    col_agent_.clear();
    stride_ = 1;
  }

  // A copy of `other` with room for one more row (add_edge's), reusing this one's buffers.
  void copy_from(const PriorityOrder& other) {
    row_of_ = other.row_of_;
    col_of_ = other.col_of_;
    rows_.reserve(other.rows_.size() + other.stride_);
    rows_.assign(other.rows_.begin(), other.rows_.end());
    row_owner_ = other.row_owner_;
    col_agent_ = other.col_agent_;
    stride_ = other.stride_;
  }

  // Room for one more row (add_edge's) without reallocating.
  void make_room() { rows_.reserve(rows_.size() + stride_); }

  // Is `higher` above `lower`?
  bool is_above(int lower, int higher) const {
    const int r = row_of_[lower], c = col_of_[higher];
    return r >= 0 && c >= 0 && ((rows_[static_cast<size_t>(r) * stride_ + (c >> 6)] >> (c & 63)) & 1u);
  }

  // Calls f(h) for every agent h above `agent`.
  template <class F>
  void for_each_above(int agent, F&& f) const {
    const int r = row_of_[agent];
    if (r < 0) return;
    const uint64_t* above = rows_.data() + static_cast<size_t>(r) * stride_;
    for (int w = 0; w < stride_; ++w)
      for (uint64_t bits = above[w]; bits; bits &= bits - 1) f(col_agent_[w * 64 + __builtin_ctzll(bits)]);
  }

  // Add "lower below higher" and keep the closure: whoever is `lower` or below it is now also
  // below `higher` and everything above `higher`. `scratch` is a caller's buffer.
  void add_edge(int lower, int higher, std::vector<uint64_t>& scratch) {
    if (col_of_[higher] < 0) {
      const int c = static_cast<int>(col_agent_.size());
      col_of_[higher] = c;
      col_agent_.push_back(higher);
      if (c >= stride_ * 64) {  // widen every row by one word
        const int old = stride_++;
        std::vector<uint64_t> wide(row_owner_.size() * stride_, 0);
        for (size_t r = 0; r < row_owner_.size(); ++r)
          std::copy(rows_.begin() + r * old, rows_.begin() + (r + 1) * old, wide.begin() + r * stride_);
        rows_ = std::move(wide);
      }
    }
    const int rh = row_of_[higher];
    if (rh >= 0)
      scratch.assign(rows_.begin() + static_cast<size_t>(rh) * stride_, rows_.begin() + static_cast<size_t>(rh + 1) * stride_);
    else
      scratch.assign(stride_, 0);
    const int ch = col_of_[higher];
    scratch[ch >> 6] |= uint64_t{1} << (ch & 63);
    auto merge = [&](int x) {
      uint64_t* r = rows_.data() + static_cast<size_t>(row_of_[x]) * stride_;
      for (int w = 0; w < stride_; ++w) r[w] |= scratch[w];
    };
    if (col_of_[lower] >= 0)  // else nobody is below `lower`
      for (int x : row_owner_)
        if (x != lower && is_above(x, lower)) merge(x);
    if (row_of_[lower] < 0) {
      row_of_[lower] = static_cast<int>(row_owner_.size());
      row_owner_.push_back(lower);
      rows_.resize(rows_.size() + stride_, 0);
    }
    merge(lower);
  }

 private:
  std::vector<int> row_of_, col_of_;
  std::vector<uint64_t> rows_;
  std::vector<int> row_owner_, col_agent_;
  int stride_ = 1;
};

}  // namespace rhcr
