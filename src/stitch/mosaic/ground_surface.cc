#include "stitch/mosaic/ground_surface.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "stitch/util/error.h"

namespace stitch {

GroundSurface::GroundSurface(double height) : heights_{height}, min_height_(height), max_height_(height) {}

GroundSurface GroundSurface::FromPoints(const std::vector<Eigen::Vector3d>& points, double cell, int min_points) {
  if (!(cell > 0) || !std::isfinite(cell)) throw Error("the ground surface's cell must be a positive size");
  std::vector<Eigen::Vector3d> finite;
  finite.reserve(points.size());
  for (const Eigen::Vector3d& p : points) {
    if (p.allFinite()) finite.push_back(p);
  }
  if (static_cast<int>(finite.size()) < std::max(1, min_points)) {
    throw Error("the map has " + std::to_string(finite.size()) + " points, too few to shape the ground");
  }
  // The grid spans the points; a stray point far away must not cost gigabytes: past kMaxCells the
  // grid spans the points between the 1st and 99th percentiles of each axis (those beyond shape
  // no cell), and where that is still too many cells, the cell grows.
  const double kMaxCells = 4e6;
  const auto cells_over = [](const Eigen::Vector2d& lo, const Eigen::Vector2d& hi, double side) {
    return (std::floor((hi.x() - lo.x()) / side) + 1) * (std::floor((hi.y() - lo.y()) / side) + 1);
  };
  Eigen::Vector2d lo = finite.front().head<2>(), hi = lo;
  for (const Eigen::Vector3d& p : finite) {
    lo = lo.cwiseMin(p.head<2>());
    hi = hi.cwiseMax(p.head<2>());
  }
  if (cells_over(lo, hi, cell) > kMaxCells) {
    for (int axis = 0; axis < 2; ++axis) {
      std::vector<double> v;
      v.reserve(finite.size());
      for (const Eigen::Vector3d& p : finite) v.push_back(p[axis]);
      const size_t low = v.size() / 100, high = v.size() - 1 - v.size() / 100;
      std::nth_element(v.begin(), v.begin() + low, v.end());
      lo[axis] = v[low];
      std::nth_element(v.begin(), v.begin() + high, v.end());
      hi[axis] = v[high];
    }
    finite.erase(std::remove_if(finite.begin(), finite.end(),
                                [&](const Eigen::Vector3d& p) {
                                  return (p.head<2>().array() < lo.array()).any() ||
                                         (p.head<2>().array() > hi.array()).any();
                                }),
                 finite.end());
    const double spread = std::max(hi.x() - lo.x(), hi.y() - lo.y());
    while (cells_over(lo, hi, cell) > kMaxCells) cell = std::max(2 * cell, spread / std::sqrt(kMaxCells));
  }
  GroundSurface surface;
  surface.cell_ = cell;
  surface.origin_ = lo + Eigen::Vector2d::Constant(0.5 * cell);
  const double cols = std::floor((hi.x() - lo.x()) / cell) + 1, rows = std::floor((hi.y() - lo.y()) / cell) + 1;
  surface.cols_ = static_cast<int>(cols);
  surface.rows_ = static_cast<int>(rows);
  std::vector<std::vector<double>> in_cell(static_cast<size_t>(surface.cols_) * surface.rows_);
  for (const Eigen::Vector3d& p : finite) {
    const int c = std::min(surface.cols_ - 1, static_cast<int>((p.x() - lo.x()) / cell));
    const int r = std::min(surface.rows_ - 1, static_cast<int>((p.y() - lo.y()) / cell));
    in_cell[static_cast<size_t>(r) * surface.cols_ + c].push_back(p.z());
  }
  const double unknown = std::numeric_limits<double>::quiet_NaN();
  surface.heights_.assign(in_cell.size(), unknown);
  surface.cells_measured_ = 0;
  for (size_t i = 0; i < in_cell.size(); ++i) {
    std::vector<double>& z = in_cell[i];
    if (static_cast<int>(z.size()) < min_points) continue;
    std::nth_element(z.begin(), z.begin() + z.size() / 2, z.end());
    surface.heights_[i] = z[z.size() / 2];
    ++surface.cells_measured_;
  }
  if (surface.cells_measured_ == 0) {
    // Points too sparse for any cell: one height for all, their median.
    std::vector<double> z;
    for (const Eigen::Vector3d& p : finite) z.push_back(p.z());
    std::nth_element(z.begin(), z.begin() + z.size() / 2, z.end());
    std::fill(surface.heights_.begin(), surface.heights_.end(), z[z.size() / 2]);
  }
  // Empty cells take the mean of their measured (or already filled) neighbours, ring by ring:
  // each ring is the empty cells next to the cells known before it, so every cell is visited a
  // few times however far it lies from the points (a map's points in one corner of a grid of
  // millions of cells).
  const int cols_n = surface.cols_, rows_n = surface.rows_;
  const auto for_each_neighbour = [&](size_t i, auto&& visit) {
    const int r = static_cast<int>(i / cols_n), c = static_cast<int>(i % cols_n);
    for (int rr = std::max(0, r - 1); rr <= std::min(rows_n - 1, r + 1); ++rr) {
      for (int cc = std::max(0, c - 1); cc <= std::min(cols_n - 1, c + 1); ++cc) {
        if (rr != r || cc != c) visit(static_cast<size_t>(rr) * cols_n + cc);
      }
    }
  };
  std::vector<char> queued(surface.heights_.size(), 0);
  std::vector<size_t> ring;
  for (size_t i = 0; i < surface.heights_.size(); ++i) {
    if (!std::isnan(surface.heights_[i])) continue;
    bool next_to_known = false;
    for_each_neighbour(i, [&](size_t j) { next_to_known |= !std::isnan(surface.heights_[j]); });
    if (next_to_known) {
      ring.push_back(i);
      queued[i] = 1;
    }
  }
  std::vector<double> filled;
  while (!ring.empty()) {
    filled.assign(ring.size(), 0.0);
    for (size_t k = 0; k < ring.size(); ++k) {
      double sum = 0;
      int n = 0;
      for_each_neighbour(ring[k], [&](size_t j) {
        const double h = surface.heights_[j];
        if (!std::isnan(h)) sum += h, ++n;
      });
      filled[k] = sum / n;  // n > 0: a ring's cells are next to a known one
    }
    for (size_t k = 0; k < ring.size(); ++k) surface.heights_[ring[k]] = filled[k];
    std::vector<size_t> next;
    for (const size_t i : ring) {
      for_each_neighbour(i, [&](size_t j) {
        if (!queued[j] && std::isnan(surface.heights_[j])) {
          queued[j] = 1;
          next.push_back(j);
        }
      });
    }
    ring = std::move(next);
  }
  const auto [min_it, max_it] = std::minmax_element(surface.heights_.begin(), surface.heights_.end());
  surface.min_height_ = *min_it;
  surface.max_height_ = *max_it;
  return surface;
}

double GroundSurface::Height(double x, double y) const {
  const double u = std::clamp((x - origin_.x()) / cell_, 0.0, static_cast<double>(cols_ - 1));
  const double v = std::clamp((y - origin_.y()) / cell_, 0.0, static_cast<double>(rows_ - 1));
  const int c = std::min(cols_ - 2, static_cast<int>(u)), r = std::min(rows_ - 2, static_cast<int>(v));
  if (cols_ == 1 || rows_ == 1) {
    // A single row or column: linear along the other axis.
    if (cols_ == 1 && rows_ == 1) return heights_[0];
    if (cols_ == 1) {
      const int r0 = std::min(rows_ - 2, static_cast<int>(v));
      const double f = v - r0;
      return (1 - f) * heights_[r0] + f * heights_[r0 + 1];
    }
    const int c0 = std::min(cols_ - 2, static_cast<int>(u));
    const double f = u - c0;
    return (1 - f) * heights_[c0] + f * heights_[c0 + 1];
  }
  const double fu = u - c, fv = v - r;
  const double* row0 = &heights_[static_cast<size_t>(r) * cols_];
  const double* row1 = row0 + cols_;
  return (1 - fv) * ((1 - fu) * row0[c] + fu * row0[c + 1]) + fv * ((1 - fu) * row1[c] + fu * row1[c + 1]);
}

}  // namespace stitch
