#pragma once
// The ground an orthomosaic lays its images on: a height grid over the horizontal plane of the
// mosaic's frame (x, y horizontal, z up), each cell the median height of the map's points in it,
// cells without enough points filled from their neighbours. Immutable once built.

#include <vector>

#include <Eigen/Core>

namespace stitch {

class GroundSurface {
 public:
  // A flat ground at `height` (a map without points to shape it).
  explicit GroundSurface(double height = 0.0);
  // From `points` (in the mosaic's frame), cells `cell` a side over the points' extent. Past 4
  // million cells (points strewn far along a room's walls, a few at a great distance) the grid
  // spans the 1st-99th percentiles of the points on each axis, and its cell grows if that is still
  // too many. Throws stitch::Error when fewer than `min_points` points are given or `cell` is not
  // positive.
  static GroundSurface FromPoints(const std::vector<Eigen::Vector3d>& points, double cell, int min_points);

  // The ground's height at (x, y): bilinear between the cells' centres, the nearest edge's
  // height beyond the grid.
  double Height(double x, double y) const;
  double min_height() const { return min_height_; }
  double max_height() const { return max_height_; }
  int cells_measured() const { return cells_measured_; }  // cells with a height of their own
  int cells() const { return cols_ * rows_; }
  double cell() const { return cell_; }

 private:
  Eigen::Vector2d origin_ = Eigen::Vector2d::Zero();  // the first cell's centre
  double cell_ = 1.0;
  int cols_ = 1, rows_ = 1;
  std::vector<double> heights_{0.0};  // row-major, row along y
  double min_height_ = 0.0, max_height_ = 0.0;
  int cells_measured_ = 0;
};

}  // namespace stitch
