// The 4-connected grid and exact single-goal distances (BFS), cached lazily per goal cell.
#pragma once

#include <cstdint>
#include <cstdlib>
#include <deque>
#include <memory>
#include <vector>

namespace rhcr {

// Direction codes: 0 up, 1 right, 2 down, 3 left; 4 is "wait".
constexpr int kWait = 4;

class Grid {
 public:
  Grid(int rows, int cols, std::vector<uint8_t> traversable)
      : rows_(rows), cols_(cols), free_(std::move(traversable)), nbr_(4 * rows * cols, -1) {
    for (int r = 0; r < rows_; ++r)
      for (int c = 0; c < cols_; ++c) {
        const int cell = r * cols_ + c;
        if (!free_[cell]) continue;
        const int dr[4] = {-1, 0, 1, 0};
        const int dc[4] = {0, 1, 0, -1};
        for (int d = 0; d < 4; ++d) {
          const int rr = r + dr[d], cc = c + dc[d];
          if (rr < 0 || rr >= rows_ || cc < 0 || cc >= cols_) continue;
          if (free_[rr * cols_ + cc]) nbr_[4 * cell + d] = rr * cols_ + cc;
        }
      }
  }

  int rows() const { return rows_; }
  int cols() const { return cols_; }
  int cells() const { return rows_ * cols_; }
  bool traversable(int cell) const { return free_[cell] != 0; }
  // Neighbour of `cell` in direction d (0..3), or -1 when off the grid or blocked.
  int neighbor(int cell, int d) const { return nbr_[4 * cell + d]; }

  int manhattan(int a, int b) const {
    return std::abs(a / cols_ - b / cols_) + std::abs(a % cols_ - b % cols_);
  }

  // Direction code of the step a -> b for 4-neighbours a, b.
  int direction(int a, int b) const {
    if (b == a - cols_) return 0;
    if (b == a + 1) return 1;
    if (b == a + cols_) return 2;
    return 3;
  }

 private:
  int rows_, cols_;
  std::vector<uint8_t> free_;
  std::vector<int> nbr_;
};

// True shortest-path distances to a goal cell, computed by BFS the first time the goal is
// used. Unreachable cells hold kUnreachable (the Python layer rejects layouts where a goal
// is unreachable, so planners never see it in practice).
class DistanceCache {
 public:
  static constexpr uint16_t kUnreachable = 0xFFFF;

  explicit DistanceCache(const Grid& grid) : grid_(grid), tables_(grid.cells()) {}

  const uint16_t* get(int goal) {
    auto& table = tables_[goal];
    if (!table) {
      table.reset(new uint16_t[grid_.cells()]);
      bfs(goal, table.get());
    }
    return table.get();
  }

 private:
  void bfs(int goal, uint16_t* dist) const {
    const int n = grid_.cells();
    for (int i = 0; i < n; ++i) dist[i] = kUnreachable;
    std::vector<int> frontier;
    frontier.reserve(n);
    dist[goal] = 0;
    frontier.push_back(goal);
    for (size_t head = 0; head < frontier.size(); ++head) {
      const int u = frontier[head];
      for (int d = 0; d < 4; ++d) {
        const int v = grid_.neighbor(u, d);
        if (v >= 0 && dist[v] == kUnreachable) {
          dist[v] = static_cast<uint16_t>(dist[u] + 1);
          frontier.push_back(v);
        }
      }
    }
  }

  const Grid& grid_;
  std::vector<std::unique_ptr<uint16_t[]>> tables_;
};

}  // namespace rhcr
