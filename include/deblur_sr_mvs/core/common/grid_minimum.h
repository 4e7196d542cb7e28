// The minimum of a 1-D grid search refined below the grid's spacing: one home
// for the searches that sample a cost on a grid (the exposure from the blur,
// the readout time from the tracks).
#pragma once

#include <cstddef>
#include <utility>
#include <vector>

namespace deblur_sr_mvs {

// grid: (x, cost) in increasing x, evenly spaced; best: the index of its
// lowest cost. The vertex of the parabola through it and its two neighbours
// (within half a step of it); the grid point itself at an end of the grid or
// where the three do not curve upwards.
inline double RefinedGridMinimum(const std::vector<std::pair<double, double>>& grid, size_t best) {
  if (best == 0 || best + 1 >= grid.size()) return grid[best].first;
  const double left = grid[best - 1].second, centre = grid[best].second, right = grid[best + 1].second;
  const double curvature = left - 2.0 * centre + right;
  if (!(curvature > 0.0)) return grid[best].first;
  const double offset = 0.5 * (left - right) / curvature;  // in grid steps, |offset| <= 0.5
  return grid[best].first + offset * (grid[best + 1].first - grid[best].first);
}

}  // namespace deblur_sr_mvs
