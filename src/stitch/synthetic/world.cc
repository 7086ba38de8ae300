#include "stitch/synthetic/world.h"

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>

#include "stitch/util/error.h"
#include "stitch/util/rng.h"

namespace stitch {
namespace {

constexpr double kRouteCell = 5.0;      // metres: the grid the route's camera centres are looked up in
constexpr double kRoadHalfWidth = 3.5;  // metres: a paved route's road is 7 m wide

// Smooth value noise in [-1, 1] on an integer lattice.
double ValueNoise(uint64_t seed, double x, double y) {
  const double fx = std::floor(x), fy = std::floor(y);
  const int64_t ix = static_cast<int64_t>(fx), iy = static_cast<int64_t>(fy);
  const auto lattice = [&](int64_t a, int64_t b) {
    return static_cast<double>(HashU64(seed, static_cast<uint64_t>(a), static_cast<uint64_t>(b)) >> 11) * 0x1.0p-52 -
           1.0;
  };
  double tx = x - fx, ty = y - fy;
  tx = tx * tx * (3 - 2 * tx);
  ty = ty * ty * (3 - 2 * ty);
  const double a = lattice(ix, iy), b = lattice(ix + 1, iy);
  const double c = lattice(ix, iy + 1), d = lattice(ix + 1, iy + 1);
  return (a * (1 - tx) + b * tx) * (1 - ty) + (c * (1 - tx) + d * tx) * ty;
}

// Fractal sum of octaves, normalized to about [-1, 1].
double Fbm(uint64_t seed, double x, double y, int octaves) {
  double sum = 0, amplitude = 1, norm = 0, frequency = 1;
  for (int o = 0; o < octaves; ++o) {
    sum += amplitude * ValueNoise(seed + 7919 * o, x * frequency, y * frequency);
    norm += amplitude;
    amplitude *= 0.5;
    frequency *= 2.0;
  }
  return sum / norm;
}

cv::Point ToTexel(const Eigen::Vector2d& world, const Eigen::Vector2d& origin, double texel) {
  return cv::Point(static_cast<int>(std::lround((world.x() - origin.x()) / texel)),
                   static_cast<int>(std::lround((world.y() - origin.y()) / texel)));
}

uint8_t Clamp8(double v) {
  return static_cast<uint8_t>(std::clamp(v, 0.0, 255.0));
}

// Anti-aliased coverage (0-255) of a polygon over its bounding box clipped to the image; empty
// when the polygon lies outside.
cv::Mat PolygonMask(const std::vector<cv::Point>& polygon, const cv::Size& image, cv::Rect* bounds) {
  *bounds = cv::boundingRect(polygon) & cv::Rect(0, 0, image.width, image.height);
  if (bounds->area() == 0) return {};
  cv::Mat mask = cv::Mat::zeros(bounds->size(), CV_8U);
  std::vector<cv::Point> local;
  for (const auto& p : polygon) local.push_back(p - bounds->tl());
  cv::fillPoly(mask, std::vector<std::vector<cv::Point>>{local}, 255, cv::LINE_AA);
  return mask;
}

// Fills a polygon, with parallel stripes inside it when stripe_spacing > 0 (crop rows).
void FillField(cv::Mat& texture, const std::vector<cv::Point>& polygon, int intensity, double stripe_angle,
               double stripe_spacing_texels, int stripe_delta) {
  cv::Rect bounds;
  const cv::Mat mask = PolygonMask(polygon, texture.size(), &bounds);
  if (mask.empty()) return;
  cv::Mat patch(bounds.size(), CV_8U, cv::Scalar(intensity));
  if (stripe_spacing_texels > 1.5) {
    const double c = std::cos(stripe_angle), s = std::sin(stripe_angle);
    const double reach = std::hypot(bounds.width, bounds.height);
    const cv::Point2d centre(bounds.width / 2.0, bounds.height / 2.0);
    const int thickness = std::max(1, static_cast<int>(stripe_spacing_texels * 0.4));
    for (double offset = -reach; offset <= reach; offset += stripe_spacing_texels) {
      const cv::Point2d base = centre + cv::Point2d(-s * offset, c * offset);
      const cv::Point a(cvRound(base.x - c * reach), cvRound(base.y - s * reach));
      const cv::Point b(cvRound(base.x + c * reach), cvRound(base.y + s * reach));
      cv::line(patch, a, b, cv::Scalar(std::clamp(intensity + stripe_delta, 0, 255)), thickness, cv::LINE_AA);
    }
  }
  // Blend by the anti-aliased mask so field borders are smooth.
  cv::Mat target = texture(bounds);
  for (int r = 0; r < bounds.height; ++r) {
    const uint8_t* m = mask.ptr<uint8_t>(r);
    const uint8_t* p = patch.ptr<uint8_t>(r);
    uint8_t* t = target.ptr<uint8_t>(r);
    for (int c = 0; c < bounds.width; ++c) {
      if (m[c]) t[c] = static_cast<uint8_t>((p[c] * m[c] + t[c] * (255 - m[c])) / 255);
    }
  }
}

// Multiplies the texture by `factor` inside a polygon (shadows).
void Darken(cv::Mat& texture, const std::vector<cv::Point>& polygon, double factor) {
  cv::Rect bounds;
  const cv::Mat mask = PolygonMask(polygon, texture.size(), &bounds);
  if (mask.empty()) return;
  cv::Mat target = texture(bounds);
  for (int r = 0; r < bounds.height; ++r) {
    const uint8_t* m = mask.ptr<uint8_t>(r);
    uint8_t* t = target.ptr<uint8_t>(r);
    for (int c = 0; c < bounds.width; ++c) {
      const double f = 1.0 - (1.0 - factor) * m[c] / 255.0;
      t[c] = static_cast<uint8_t>(t[c] * f);
    }
  }
}

}  // namespace

bool WorldOptions::Check(std::string* why) const {
  auto fail = [&](const std::string& m) {
    if (why) *why = m;
    return false;
  };
  if (!(grid_spacing_m > 0.05 && grid_spacing_m <= 20)) return fail("world.grid_spacing_m must be in (0.05, 20]");
  if (!(texel_m > 0.005 && texel_m <= 2)) return fail("world.texel_m must be in (0.005, 2]");
  if (!(relief_m >= 0)) return fail("world.relief_m must be >= 0");
  if (!(hill_wavelength_m > 1)) return fail("world.hill_wavelength_m must be > 1");
  if (num_buildings < 0 || num_buildings > 10000) return fail("world.num_buildings must be in [0, 10000]");
  if (!(building_min_height_m > 0 && building_min_height_m <= building_max_height_m)) {
    return fail("world.building_min_height_m must be > 0 and <= building_max_height_m");
  }
  if (!(building_min_side_m > 0 && building_min_side_m <= building_max_side_m)) {
    return fail("world.building_min_side_m must be > 0 and <= building_max_side_m");
  }
  if (!(visibility_m >= 0)) return fail("world.visibility_m must be >= 0");
  return true;
}

std::array<Eigen::Vector2d, 4> Building::Corners() const {
  const Eigen::Vector2d ax(std::cos(yaw), std::sin(yaw));
  const Eigen::Vector2d ay(-ax.y(), ax.x());
  return {centre - half_length * ax - half_width * ay, centre + half_length * ax - half_width * ay,
          centre + half_length * ax + half_width * ay, centre - half_length * ax + half_width * ay};
}

SyntheticWorld::SyntheticWorld(const WorldOptions& options, uint64_t seed, const Eigen::Vector2d& min_xy,
                               const Eigen::Vector2d& max_xy, const WorldRoute& route)
    : options_(options), min_xy_(min_xy), max_xy_(max_xy), route_(route) {
  std::string why;
  if (!options_.Check(&why)) throw Error(why);
  if (!((max_xy - min_xy).minCoeff() > 2 * options_.grid_spacing_m)) {
    throw Error("synthetic world: extent is too small");
  }
  sun_direction_ =
      Eigen::Vector3d(std::cos(0.8) * std::cos(2.3), std::cos(0.8) * std::sin(2.3), std::sin(0.8)).normalized();
  for (size_t i = 0; i < route_.camera_centres.size(); ++i) {
    const Eigen::Vector3d& c = route_.camera_centres[i];
    route_cells_[{static_cast<int>(std::floor(c.x() / kRouteCell)), static_cast<int>(std::floor(c.y() / kRouteCell))}]
        .push_back(i);
  }
  BuildTerrain(seed);
  PlaceBuildings(seed + 101);
  if (route_.paved) PlaceStreetBuildings(seed + 404);
  FlattenUnderBuildings();
  ComputeShading();
  PaintGround(seed + 202);
  PaintFacades(seed + 303);
}

void SyntheticWorld::BuildTerrain(uint64_t seed) {
  grid_cols_ = static_cast<int>(std::ceil((max_xy_.x() - min_xy_.x()) / spacing())) + 1;
  grid_rows_ = static_cast<int>(std::ceil((max_xy_.y() - min_xy_.y()) / spacing())) + 1;
  max_xy_ = min_xy_ + Eigen::Vector2d((grid_cols_ - 1) * spacing(), (grid_rows_ - 1) * spacing());
  heights_.resize(static_cast<size_t>(grid_cols_) * grid_rows_);
  for (int r = 0; r < grid_rows_; ++r) {
    for (int c = 0; c < grid_cols_; ++c) {
      const double x = min_xy_.x() + c * spacing();
      const double y = min_xy_.y() + r * spacing();
      heights_[r * grid_cols_ + c] = static_cast<float>(
          options_.relief_m * Fbm(seed, x / options_.hill_wavelength_m, y / options_.hill_wavelength_m, 4));
    }
  }
}

void SyntheticWorld::PlaceBuildings(uint64_t seed) {
  Rng rng(seed);
  const Eigen::Vector2d size = max_xy_ - min_xy_;
  // Buildings gather in a few villages, so the flight sees towns, fields and woods.
  const int num_villages = std::max(1, options_.num_buildings / 20);
  std::vector<Eigen::Vector2d> villages;
  for (int v = 0; v < num_villages; ++v) {
    villages.emplace_back(min_xy_.x() + rng.Uniform(0.15, 0.85) * size.x(),
                          min_xy_.y() + rng.Uniform(0.15, 0.85) * size.y());
  }
  int attempts = 0;
  while (static_cast<int>(buildings_.size()) < options_.num_buildings &&
         attempts++ < 200 * options_.num_buildings + 100) {
    const Eigen::Vector2d& village = villages[rng.UniformInt(0, num_villages - 1)];
    Building b;
    b.centre = village + Eigen::Vector2d(rng.Normal(0, 45), rng.Normal(0, 45));
    b.half_length = 0.5 * rng.Uniform(options_.building_min_side_m, options_.building_max_side_m);
    b.half_width =
        0.5 * rng.Uniform(options_.building_min_side_m, std::max(options_.building_min_side_m, 2 * b.half_length));
    b.yaw = rng.Uniform(0, M_PI);
    b.height = rng.Uniform(options_.building_min_height_m, options_.building_max_height_m);
    b.facade_offset_m = rng.Uniform(0, 400);
    b.wall_brightness = static_cast<float>(rng.Uniform(0.75, 1.2));
    if (CanStand(&b, 4.0)) buildings_.push_back(b);
  }
}

bool SyntheticWorld::CanStand(Building* b, double spacing) const {
  const double radius = std::hypot(b->half_length, b->half_width);
  if (b->centre.x() - radius < min_xy_.x() + 10 || b->centre.y() - radius < min_xy_.y() + 10 ||
      b->centre.x() + radius > max_xy_.x() - 10 || b->centre.y() + radius > max_xy_.y() - 10) {
    return false;
  }
  for (const auto& other : buildings_) {
    if ((other.centre - b->centre).norm() < radius + std::hypot(other.half_length, other.half_width) + spacing) {
      return false;
    }
  }
  b->base_z = TerrainHeight(b->centre.x(), b->centre.y());
  return !InTheWay(*b);
}

bool SyntheticWorld::InTheWay(const Building& b) const {
  // Room for a camera to pass by, or the road's half width and a pavement.
  const double margin = route_.paved ? kRoadHalfWidth + 2.0 : 3.0;
  return RouteDistance(b, b.base_z + b.height + 2.0, margin) < margin;
}

double SyntheticWorld::RouteDistance(const Building& b, double roof_z, double reach) const {
  if (route_cells_.empty()) return reach;
  const double radius = std::hypot(b.half_length, b.half_width) + reach;
  const int x0 = static_cast<int>(std::floor((b.centre.x() - radius) / kRouteCell));
  const int x1 = static_cast<int>(std::floor((b.centre.x() + radius) / kRouteCell));
  const int y0 = static_cast<int>(std::floor((b.centre.y() - radius) / kRouteCell));
  const int y1 = static_cast<int>(std::floor((b.centre.y() + radius) / kRouteCell));
  const Eigen::Vector2d ax(std::cos(b.yaw), std::sin(b.yaw)), ay(-ax.y(), ax.x());
  double nearest = reach;
  for (int x = x0; x <= x1; ++x) {
    for (int y = y0; y <= y1; ++y) {
      const auto it = route_cells_.find({x, y});
      if (it == route_cells_.end()) continue;
      for (const size_t i : it->second) {
        const Eigen::Vector3d& c = route_.camera_centres[i];
        if (!route_.paved && c.z() >= roof_z) continue;
        const Eigen::Vector2d d = c.head<2>() - b.centre;
        const Eigen::Vector2d outside(std::max(std::abs(d.dot(ax)) - b.half_length, 0.0),
                                      std::max(std::abs(d.dot(ay)) - b.half_width, 0.0));
        nearest = std::min(nearest, outside.norm());
      }
    }
  }
  return nearest;
}

void SyntheticWorld::PlaceStreetBuildings(uint64_t seed) {
  // Houses and blocks along both sides of the road, facing it, with gaps between them.
  Rng rng(seed);
  const auto& centres = route_.camera_centres;
  double travelled = 0, next = rng.Uniform(5, 15);
  for (size_t i = 1; i < centres.size(); ++i) {
    const Eigen::Vector2d step = (centres[i] - centres[i - 1]).head<2>();
    travelled += step.norm();
    if (travelled < next || step.norm() <= 0) continue;
    next = travelled + rng.Uniform(14, 30);
    const Eigen::Vector2d along = step.normalized(), across(-along.y(), along.x());
    for (const double side : {-1.0, 1.0}) {
      if (rng.Uniform() < 0.2) continue;  // a gap: a yard, a side street
      Building b;
      b.half_length = 0.5 * rng.Uniform(std::max(options_.building_min_side_m, 8.0), 18.0);  // along the road
      b.half_width = 0.5 * rng.Uniform(options_.building_min_side_m, std::max(options_.building_min_side_m, 14.0));
      const double setback = rng.Uniform(3.0, 9.0);
      b.centre = centres[i].head<2>() + side * (kRoadHalfWidth + setback + b.half_width) * across;
      b.yaw = std::atan2(along.y(), along.x());
      b.height = rng.Uniform(options_.building_min_height_m, options_.building_max_height_m);
      b.facade_offset_m = rng.Uniform(0, 400);
      b.wall_brightness = static_cast<float>(rng.Uniform(0.75, 1.2));
      if (CanStand(&b, 1.0)) buildings_.push_back(b);
    }
  }
}

void SyntheticWorld::FlattenUnderBuildings() {
  // Terrain vertices under and just around a building take its base height, blending back to the
  // hills over a few metres, so walls meet the ground.
  const double margin = 1.5 + spacing(), blend = 6.0;
  for (const auto& b : buildings_) {
    const Eigen::Vector2d ax(std::cos(b.yaw), std::sin(b.yaw));
    const Eigen::Vector2d ay(-ax.y(), ax.x());
    const double reach = std::hypot(b.half_length, b.half_width) + margin + blend;
    const int c0 = std::max(0, static_cast<int>((b.centre.x() - reach - min_xy_.x()) / spacing()));
    const int c1 = std::min(grid_cols_ - 1, static_cast<int>((b.centre.x() + reach - min_xy_.x()) / spacing()) + 1);
    const int r0 = std::max(0, static_cast<int>((b.centre.y() - reach - min_xy_.y()) / spacing()));
    const int r1 = std::min(grid_rows_ - 1, static_cast<int>((b.centre.y() + reach - min_xy_.y()) / spacing()) + 1);
    for (int r = r0; r <= r1; ++r) {
      for (int c = c0; c <= c1; ++c) {
        const Eigen::Vector2d d = Eigen::Vector2d(min_xy_.x() + c * spacing(), min_xy_.y() + r * spacing()) - b.centre;
        const double outside =
            std::max(std::abs(d.dot(ax)) - b.half_length, std::abs(d.dot(ay)) - b.half_width) - margin;
        float& h = heights_[r * grid_cols_ + c];
        if (outside <= 0) {
          h = static_cast<float>(b.base_z);
        } else if (outside < blend) {
          const double w = outside / blend;
          h = static_cast<float>(b.base_z * (1 - w) + h * w);
        }
      }
    }
  }
  min_height_ = *std::min_element(heights_.begin(), heights_.end());
  max_height_ = *std::max_element(heights_.begin(), heights_.end());
  for (const auto& b : buildings_) max_height_ = std::max(max_height_, b.base_z + b.height);
}

void SyntheticWorld::ComputeShading() {
  shades_.resize(heights_.size());
  constexpr double kAmbient = 0.5;
  for (int r = 0; r < grid_rows_; ++r) {
    for (int c = 0; c < grid_cols_; ++c) {
      const int cl = std::max(c - 1, 0), cr = std::min(c + 1, grid_cols_ - 1);
      const int rd = std::max(r - 1, 0), ru = std::min(r + 1, grid_rows_ - 1);
      const double dhdx = (VertexHeight(cr, r) - VertexHeight(cl, r)) / ((cr - cl) * spacing());
      const double dhdy = (VertexHeight(c, ru) - VertexHeight(c, rd)) / ((ru - rd) * spacing());
      const Eigen::Vector3d normal = Eigen::Vector3d(-dhdx, -dhdy, 1).normalized();
      const double lambert = std::max(0.0, normal.dot(sun_direction_)) / sun_direction_.z();
      shades_[r * grid_cols_ + c] = static_cast<float>(std::min(1.3, kAmbient + (1 - kAmbient) * lambert));
    }
  }
}

float SyntheticWorld::WallShade(const Eigen::Vector2d& outward_normal) const {
  const double lambert = std::max(0.0, outward_normal.normalized().dot(sun_direction_.head<2>())) / sun_direction_.z();
  return static_cast<float>(0.45 + 0.45 * lambert);
}

double SyntheticWorld::TerrainHeight(double x, double y) const {
  const double gx = std::clamp((x - min_xy_.x()) / spacing(), 0.0, grid_cols_ - 1.000001);
  const double gy = std::clamp((y - min_xy_.y()) / spacing(), 0.0, grid_rows_ - 1.000001);
  const int c = static_cast<int>(gx), r = static_cast<int>(gy);
  const double fx = gx - c, fy = gy - r;
  const double ha = VertexHeight(c, r), hb = VertexHeight(c + 1, r);
  const double hc = VertexHeight(c + 1, r + 1), hd = VertexHeight(c, r + 1);
  // The same split as the renderer's triangles (a, b, c) and (a, c, d).
  if (fy <= fx) return ha + fx * (hb - ha) + fy * (hc - hb);
  return ha + fy * (hd - ha) + fx * (hc - hd);
}

void SyntheticWorld::PaintGround(uint64_t seed) {
  Rng rng(seed);
  const double texel = options_.texel_m;
  const Eigen::Vector2d size = max_xy_ - min_xy_;
  const int cols = static_cast<int>(std::ceil(size.x() / texel)) + 1;
  const int rows = static_cast<int>(std::ceil(size.y() / texel)) + 1;
  cv::Mat texture(rows, cols, CV_8U, cv::Scalar(115));
  const auto to_texel = [&](const Eigen::Vector2d& w) { return ToTexel(w, min_xy_, texel); };
  const double area = size.x() * size.y();

  // Fields: overlapping jittered quadrilaterals, many with crop rows.
  const int num_fields = static_cast<int>(area / 2500.0) + 4;
  for (int f = 0; f < num_fields; ++f) {
    const Eigen::Vector2d centre(min_xy_.x() + rng.Uniform() * size.x(), min_xy_.y() + rng.Uniform() * size.y());
    const double half_a = rng.Uniform(15, 50), half_b = rng.Uniform(15, 50), yaw = rng.Uniform(0, M_PI);
    const Eigen::Vector2d ax(std::cos(yaw), std::sin(yaw)), ay(-std::sin(yaw), std::cos(yaw));
    std::vector<cv::Point> polygon;
    const double sx[] = {-1, 1, 1, -1}, sy[] = {-1, -1, 1, 1};
    for (int k = 0; k < 4; ++k) {
      const Eigen::Vector2d corner =
          centre + sx[k] * half_a * ax + sy[k] * half_b * ay + Eigen::Vector2d(rng.Normal(0, 4), rng.Normal(0, 4));
      polygon.push_back(to_texel(corner));
    }
    const int intensity = rng.UniformInt(55, 200);
    const bool striped = rng.Uniform() < 0.6;
    FillField(texture, polygon, intensity, yaw + (rng.Uniform() < 0.5 ? 0 : M_PI / 2),
              striped ? rng.Uniform(1.2, 4.0) / texel : 0, rng.UniformInt(-35, 35));
  }

  // Roads: long polylines with a dashed centre line.
  const int num_roads = std::max(2, static_cast<int>(std::sqrt(area) / 120));
  for (int k = 0; k < num_roads; ++k) {
    std::vector<cv::Point> road;
    Eigen::Vector2d p(min_xy_.x() + rng.Uniform() * size.x(), min_xy_.y());
    double heading = M_PI / 2 + rng.Normal(0, 0.4);
    if (k % 2) {
      p = Eigen::Vector2d(min_xy_.x(), min_xy_.y() + rng.Uniform() * size.y());
      heading = rng.Normal(0, 0.4);
    }
    for (int s = 0; s < 200; ++s) {
      road.push_back(to_texel(p));
      heading += rng.Normal(0, 0.08);
      p += 8.0 * Eigen::Vector2d(std::cos(heading), std::sin(heading));
    }
    const int width = static_cast<int>(rng.Uniform(4, 7) / texel);
    cv::polylines(texture, road, false, cv::Scalar(rng.UniformInt(60, 90)), width + static_cast<int>(1.0 / texel),
                  cv::LINE_AA);
    cv::polylines(texture, road, false, cv::Scalar(rng.UniformInt(150, 200)), width, cv::LINE_AA);
    for (size_t s = 0; s + 1 < road.size(); s += 2) {
      cv::line(texture, road[s], road[s + 1], cv::Scalar(235), std::max(1, static_cast<int>(0.2 / texel)), cv::LINE_AA);
    }
  }

  if (route_.paved) PaintRoad(seed + 505, &texture);

  // Building shadows, cast away from the sun, then the roofs.
  const Eigen::Vector2d shadow_per_metre = -sun_direction_.head<2>() / sun_direction_.z();
  for (const auto& b : buildings_) {
    std::vector<cv::Point> hull_input;
    for (const auto& c : b.Corners()) {
      hull_input.push_back(to_texel(c));
      hull_input.push_back(to_texel(c + b.height * shadow_per_metre));
    }
    std::vector<cv::Point> hull;
    cv::convexHull(hull_input, hull);
    Darken(texture, hull, 0.55);
  }

  // Trees: woods and scattered single trees, each a dark crown with a sunlit side and a shadow.
  const int num_woods = static_cast<int>(area / 20000.0) + 2;
  std::vector<std::pair<Eigen::Vector2d, double>> tree_spots;
  for (int w = 0; w < num_woods; ++w) {
    const Eigen::Vector2d centre(min_xy_.x() + rng.Uniform() * size.x(), min_xy_.y() + rng.Uniform() * size.y());
    const double spread = rng.Uniform(10, 35);
    const int count = rng.UniformInt(60, 250);
    for (int t = 0; t < count; ++t)
      tree_spots.push_back(
          {centre + Eigen::Vector2d(rng.Normal(0, spread), rng.Normal(0, spread)), rng.Uniform(1.0, 3.0)});
  }
  const int scattered = static_cast<int>(area / 300.0);
  for (int t = 0; t < scattered; ++t) {
    tree_spots.push_back(
        {Eigen::Vector2d(min_xy_.x() + rng.Uniform() * size.x(), min_xy_.y() + rng.Uniform() * size.y()),
         rng.Uniform(0.8, 2.5)});
  }
  const Eigen::Vector2d sun_offset = sun_direction_.head<2>().normalized();
  for (const auto& [centre, radius] : tree_spots) {
    const int r = std::max(2, static_cast<int>(radius / texel));
    const double height = 2.5 * radius;
    cv::circle(texture, to_texel(centre + height * 0.4 * shadow_per_metre), r, cv::Scalar(rng.UniformInt(20, 45)),
               cv::FILLED, cv::LINE_AA);
    cv::circle(texture, to_texel(centre), r, cv::Scalar(rng.UniformInt(35, 80)), cv::FILLED, cv::LINE_AA);
    cv::circle(texture, to_texel(centre + 0.35 * radius * sun_offset), std::max(1, r / 2),
               cv::Scalar(rng.UniformInt(80, 130)), cv::FILLED, cv::LINE_AA);
  }

  // Small things: stones, bushes, marks.
  const int num_dots = static_cast<int>(area / 25.0);
  for (int d = 0; d < num_dots; ++d) {
    const cv::Point p(rng.UniformInt(0, cols - 1), rng.UniformInt(0, rows - 1));
    const int r = std::max(1, static_cast<int>(rng.Uniform(0.15, 0.5) / texel));
    cv::circle(texture, p, r, cv::Scalar(rng.UniformInt(30, 220)), cv::FILLED, cv::LINE_AA);
  }

  // Roofs: gabled or flat, with a few boxes (vents, skylights) on top.
  for (const auto& b : buildings_) {
    const auto corners = b.Corners();
    std::vector<cv::Point> roof;
    for (const auto& c : corners) roof.push_back(to_texel(c));
    const int base = rng.UniformInt(70, 220);
    cv::fillPoly(texture, std::vector<std::vector<cv::Point>>{roof}, cv::Scalar(base), cv::LINE_AA);
    const Eigen::Vector2d ax(std::cos(b.yaw), std::sin(b.yaw)), ay(-ax.y(), ax.x());
    if (rng.Uniform() < 0.6) {
      // Gabled: one half in the sun, one in shade, ridge along the long side.
      std::vector<cv::Point> half{to_texel(corners[0]), to_texel(corners[1]), to_texel(b.centre + b.half_length * ax),
                                  to_texel(b.centre - b.half_length * ax)};
      cv::fillPoly(texture, std::vector<std::vector<cv::Point>>{half}, cv::Scalar(Clamp8(base * 0.65)), cv::LINE_AA);
      cv::line(texture, to_texel(b.centre - b.half_length * ax), to_texel(b.centre + b.half_length * ax),
               cv::Scalar(Clamp8(base * 1.2)), std::max(1, static_cast<int>(0.4 / texel)), cv::LINE_AA);
    } else {
      cv::polylines(texture, roof, true, cv::Scalar(Clamp8(base * 0.5)), std::max(1, static_cast<int>(0.5 / texel)),
                    cv::LINE_AA);
      const int boxes = rng.UniformInt(1, 5);
      for (int k = 0; k < boxes; ++k) {
        const Eigen::Vector2d c =
            b.centre + rng.Uniform(-0.6, 0.6) * b.half_length * ax + rng.Uniform(-0.6, 0.6) * b.half_width * ay;
        const double s = rng.Uniform(0.6, 2.0);
        std::vector<cv::Point> box{to_texel(c - s * ax - s * ay), to_texel(c + s * ax - s * ay),
                                   to_texel(c + s * ax + s * ay), to_texel(c - s * ax + s * ay)};
        cv::fillPoly(texture, std::vector<std::vector<cv::Point>>{box}, cv::Scalar(rng.UniformInt(20, 250)),
                     cv::LINE_AA);
      }
    }
  }

  // Large-scale brightness variation and fine grain.
  cv::Mat low(std::max(2, rows / 400), std::max(2, cols / 400), CV_32F);
  for (int r = 0; r < low.rows; ++r) {
    for (int c = 0; c < low.cols; ++c) low.at<float>(r, c) = static_cast<float>(rng.Uniform(0.8, 1.2));
  }
  cv::Mat modulation;
  cv::resize(low, modulation, texture.size(), 0, 0, cv::INTER_CUBIC);
  // Grain at two scales: soil and grass clumps of about a metre, and texel-level noise.
  cv::RNG cv_rng(seed);
  cv::Mat clumps_low(std::max(2, rows / 8), std::max(2, cols / 8), CV_32F);
  cv_rng.fill(clumps_low, cv::RNG::NORMAL, 0.0, 9.0);
  cv::Mat clumps;
  cv::resize(clumps_low, clumps, texture.size(), 0, 0, cv::INTER_CUBIC);
  cv::Mat grain(texture.size(), CV_32F);
  cv_rng.fill(grain, cv::RNG::NORMAL, 0.0, 7.0);
  cv::Mat as_float;
  texture.convertTo(as_float, CV_32F);
  as_float = as_float.mul(modulation) + clumps + grain;
  as_float.convertTo(texture, CV_8U);

  ground_.texel_m = texel;
  ground_.wrap_u = false;
  ground_.levels = {texture};
  BuildMipLevels(&ground_);
}

void SyntheticWorld::PaintRoad(uint64_t seed, cv::Mat* texture) const {
  Rng rng(seed);
  const double texel = options_.texel_m;
  const auto to_texel = [&](const Eigen::Vector2d& w) { return ToTexel(w, min_xy_, texel); };
  // The route's ground track, a point every metre or so, each with its arc length and its left.
  std::vector<Eigen::Vector2d> track;
  std::vector<double> arc;
  for (const Eigen::Vector3d& c : route_.camera_centres) {
    if (!track.empty() && (c.head<2>() - track.back()).norm() < 1.0) continue;
    arc.push_back(track.empty() ? 0.0 : arc.back() + (c.head<2>() - track.back()).norm());
    track.push_back(c.head<2>());
  }
  if (track.size() < 2) return;
  std::vector<Eigen::Vector2d> left(track.size());
  for (size_t i = 0; i < track.size(); ++i) {
    const Eigen::Vector2d along = (track[std::min(i + 1, track.size() - 1)] - track[i > 0 ? i - 1 : 0]).normalized();
    left[i] = Eigen::Vector2d(-along.y(), along.x());
  }
  const auto offset_line = [&](double offset) {
    std::vector<cv::Point> line;
    for (size_t i = 0; i < track.size(); ++i) line.push_back(to_texel(track[i] + offset * left[i]));
    return line;
  };
  const auto thick = [&](double metres) { return std::max(1, static_cast<int>(std::lround(metres / texel))); };
  // Pavements, kerbs, asphalt.
  cv::polylines(*texture, offset_line(0), false, cv::Scalar(rng.UniformInt(135, 160)), thick(2 * kRoadHalfWidth + 5),
                cv::LINE_AA);
  cv::polylines(*texture, offset_line(0), false, cv::Scalar(rng.UniformInt(185, 210)), thick(2 * kRoadHalfWidth + 0.6),
                cv::LINE_AA);
  cv::polylines(*texture, offset_line(0), false, cv::Scalar(rng.UniformInt(60, 80)), thick(2 * kRoadHalfWidth),
                cv::LINE_AA);
  // Patches of newer and older asphalt, and manhole covers.
  for (size_t i = 0; i < track.size(); i += 4) {
    if (rng.Uniform() < 0.15) {
      const Eigen::Vector2d c = track[i] + rng.Uniform(-2.5, 2.5) * left[i];
      cv::circle(*texture, to_texel(c), thick(rng.Uniform(0.3, 1.2)), cv::Scalar(rng.UniformInt(40, 110)), cv::FILLED,
                 cv::LINE_AA);
    }
  }
  // Edge lines, and a centre line of 3 m dashes 6 m apart.
  cv::polylines(*texture, offset_line(kRoadHalfWidth - 0.3), false, cv::Scalar(225), thick(0.15), cv::LINE_AA);
  cv::polylines(*texture, offset_line(-(kRoadHalfWidth - 0.3)), false, cv::Scalar(225), thick(0.15), cv::LINE_AA);
  for (size_t i = 0; i + 1 < track.size(); ++i) {
    if (std::fmod(arc[i], 9.0) < 3.0)
      cv::line(*texture, to_texel(track[i]), to_texel(track[i + 1]), cv::Scalar(235), thick(0.15), cv::LINE_AA);
  }
}

void SyntheticWorld::PaintFacades(uint64_t seed) {
  Rng rng(seed);
  const double texel = options_.texel_m;
  const int cols = static_cast<int>(std::lround(409.6 / texel));
  const int rows = static_cast<int>(std::lround(std::max(options_.building_max_height_m, 1.0) / texel)) + 8;
  cv::Mat texture(rows, cols, CV_8U, cv::Scalar(140));
  // Segments of one facade style each: wall colour, floors, window grid.
  int x = 0;
  while (x < cols) {
    const int length = static_cast<int>(rng.Uniform(15, 50) / texel);
    const int wall = rng.UniformInt(90, 210);
    cv::rectangle(texture, cv::Rect(x, 0, length, rows), cv::Scalar(wall), cv::FILLED);
    const double floor_h = rng.Uniform(2.8, 3.6), spacing = rng.Uniform(2.2, 4.0);
    const double win_w = rng.Uniform(0.8, std::min(1.8, spacing - 0.4)), win_h = rng.Uniform(1.0, 1.8);
    for (double v = 0.9; v + win_h < rows * texel; v += floor_h) {
      cv::line(texture, cv::Point(x, static_cast<int>(v / texel) - 3),
               cv::Point(x + length, static_cast<int>(v / texel) - 3), cv::Scalar(Clamp8(wall * 0.7)), 2);
      for (double u = 0.5; u + win_w < length * texel; u += spacing) {
        const cv::Rect window(x + static_cast<int>(u / texel), static_cast<int>(v / texel),
                              static_cast<int>(win_w / texel), static_cast<int>(win_h / texel));
        const int glass = rng.Uniform() < 0.15 ? rng.UniformInt(180, 240) : rng.UniformInt(15, 70);
        cv::rectangle(texture, window, cv::Scalar(glass), cv::FILLED);
        cv::rectangle(texture, window, cv::Scalar(Clamp8(wall * 1.15)), 1);
      }
    }
    x += length;
  }
  cv::Mat grain(texture.size(), CV_8U);
  cv::RNG cv_rng(seed);
  cv_rng.fill(grain, cv::RNG::UNIFORM, 0, 14);
  texture = texture + grain;
  facade_.texel_m = texel;
  facade_.wrap_u = true;
  facade_.levels = {texture};
  BuildMipLevels(&facade_);
}

void SyntheticWorld::PaintMarker(double x, double y, double radius_m) {
  cv::Mat& level0 = ground_.levels.front();
  const cv::Point2d centre((x - min_xy_.x()) / ground_.texel_m, (y - min_xy_.y()) / ground_.texel_m);
  constexpr int kShift = 4;  // sub-texel centre
  cv::circle(level0, cv::Point(cvRound(centre.x * (1 << kShift)), cvRound(centre.y * (1 << kShift))),
             static_cast<int>(radius_m / ground_.texel_m * 2.0 * (1 << kShift)), cv::Scalar(0), cv::FILLED, cv::LINE_AA,
             kShift);
  cv::circle(level0, cv::Point(cvRound(centre.x * (1 << kShift)), cvRound(centre.y * (1 << kShift))),
             static_cast<int>(radius_m / ground_.texel_m * (1 << kShift)), cv::Scalar(255), cv::FILLED, cv::LINE_AA,
             kShift);
  BuildMipLevels(&ground_);
}

void BuildMipLevels(MipTexture* texture) {
  texture->levels.resize(1);
  while (std::min(texture->levels.back().cols, texture->levels.back().rows) > 16) {
    cv::Mat next;
    cv::pyrDown(texture->levels.back(), next);
    texture->levels.push_back(next);
  }
}

}  // namespace stitch
