#pragma once
// A synthetic world for the embedded default flight: textured terrain with relief, fields, trees,
// roads, and buildings with roofs and facades. Deterministic from its seed. Immutable after
// construction, so one world can be rendered from several threads.

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

namespace stitch {

struct WorldOptions {
  double grid_spacing_m = 1.0;     // terrain mesh resolution
  double texel_m = 0.1;            // ground texture resolution
  double relief_m = 8.0;           // amplitude of the hills (peak to mean)
  double hill_wavelength_m = 160;  // size of the largest hills
  int num_buildings = 50;
  double building_min_height_m = 5.0;
  double building_max_height_m = 18.0;
  double building_min_side_m = 8.0;
  double building_max_side_m = 26.0;
  // Haze: the distance at which the ground is barely told from the sky (contrast 2%, as
  // meteorological visibility is defined); 0: a clear view. What a forward camera sees near the
  // horizon fades into the sky instead of ending at the edge of the world.
  double visibility_m = 0.0;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("grid_spacing_m", grid_spacing_m, "terrain mesh resolution, metres");
    v("texel_m", texel_m, "ground texture resolution, metres per texel");
    v("relief_m", relief_m, "amplitude of the hills, metres");
    v("hill_wavelength_m", hill_wavelength_m, "size of the largest hills, metres");
    v("num_buildings", num_buildings, "buildings placed in the world");
    v("building_min_height_m", building_min_height_m, "");
    v("building_max_height_m", building_max_height_m, "");
    v("building_min_side_m", building_min_side_m, "");
    v("building_max_side_m", building_max_side_m, "");
    v("visibility_m", visibility_m, "haze: distance at which the ground fades into the sky, metres (0: clear)");
  }
  bool Check(std::string* why) const;
};

struct Building {
  Eigen::Vector2d centre;  // world x, y
  double half_length = 0;  // along its own x axis
  double half_width = 0;
  double yaw = 0;  // radians, of its x axis from world x
  double base_z = 0;
  double height = 0;
  double facade_offset_m = 0;  // where its walls start in the facade texture
  float wall_brightness = 1.0f;

  // Footprint corners, counter-clockwise seen from above.
  std::array<Eigen::Vector2d, 4> Corners() const;
};

// A texture and its mip levels (level 0 full resolution, each next level half size).
struct MipTexture {
  std::vector<cv::Mat> levels;  // CV_8UC1
  double texel_m = 0.1;         // metres per texel at level 0
  bool wrap_u = false;          // repeat horizontally (facades)
};

// The way the camera takes through the world, so the world is built around it.
struct WorldRoute {
  // The planned camera centres (world x, y, z). No building stands where the camera passes below
  // its roof (with 3 m to spare around it and 2 m above it): an aircraft flies round or over
  // buildings, and a car's road runs between them.
  std::vector<Eigen::Vector3d> camera_centres;
  // A road along the route, as a car drives on: asphalt 7 m wide with edge lines and a dashed
  // centre line, and buildings along both sides (a street).
  bool paved = false;
};

class SyntheticWorld {
 public:
  // The world covers [min_xy, max_xy] (metres), built around `route`. Throws stitch::Error on
  // invalid options.
  SyntheticWorld(const WorldOptions& options, uint64_t seed, const Eigen::Vector2d& min_xy,
                 const Eigen::Vector2d& max_xy, const WorldRoute& route = {});

  const WorldOptions& options() const { return options_; }
  const Eigen::Vector2d& min_xy() const { return min_xy_; }
  const Eigen::Vector2d& max_xy() const { return max_xy_; }
  int grid_cols() const { return grid_cols_; }  // vertices along x
  int grid_rows() const { return grid_rows_; }  // vertices along y
  double spacing() const { return options_.grid_spacing_m; }
  float VertexHeight(int col, int row) const { return heights_[row * grid_cols_ + col]; }
  float VertexShade(int col, int row) const { return shades_[row * grid_cols_ + col]; }
  Eigen::Vector3d Vertex(int col, int row) const {
    return {min_xy_.x() + col * spacing(), min_xy_.y() + row * spacing(), VertexHeight(col, row)};
  }

  // Height of the terrain surface (not the buildings) exactly as the mesh renders it.
  double TerrainHeight(double x, double y) const;
  // Highest point of terrain or building anywhere (for visibility bounds).
  double MaxHeight() const { return max_height_; }
  double MinHeight() const { return min_height_; }

  const std::vector<Building>& buildings() const { return buildings_; }
  const MipTexture& ground() const { return ground_; }
  const MipTexture& facade() const { return facade_; }
  float WallShade(const Eigen::Vector2d& outward_normal) const;

  // For tests: paints a bright disc of `radius_m` on the ground texture at world (x, y).
  void PaintMarker(double x, double y, double radius_m);

 private:
  void BuildTerrain(uint64_t seed);
  void PlaceBuildings(uint64_t seed);
  void PlaceStreetBuildings(uint64_t seed);
  // Whether building `b` fits: inside the world, `spacing` metres from every other, out of the
  // route's way. Sets its base height.
  bool CanStand(Building* b, double spacing) const;
  // Whether building `b` would stand where the route passes below its roof, or on its road.
  bool InTheWay(const Building& b) const;
  // The least horizontal distance from the footprint of `b` to a camera centre of the route that
  // passes below `roof_z` (any, when the route is paved), within `reach`; `reach` when none is.
  double RouteDistance(const Building& b, double roof_z, double reach) const;
  void PaintRoad(uint64_t seed, cv::Mat* texture) const;
  void FlattenUnderBuildings();
  void ComputeShading();
  void PaintGround(uint64_t seed);
  void PaintFacades(uint64_t seed);

  WorldOptions options_;
  Eigen::Vector2d min_xy_, max_xy_;
  int grid_cols_ = 0, grid_rows_ = 0;
  std::vector<float> heights_;
  std::vector<float> shades_;
  std::vector<Building> buildings_;
  WorldRoute route_;
  // Which of the route's camera centres pass over each 5 m cell (x cell, y cell): indices into
  // route_.camera_centres.
  std::map<std::pair<int, int>, std::vector<size_t>> route_cells_;
  MipTexture ground_;
  MipTexture facade_;
  Eigen::Vector3d sun_direction_;  // unit, towards the sun
  double max_height_ = 0, min_height_ = 0;
};

// Rebuilds levels[1..] from levels[0].
void BuildMipLevels(MipTexture* texture);

}  // namespace stitch
