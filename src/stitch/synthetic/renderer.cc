#include "stitch/synthetic/renderer.h"

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>

namespace stitch {
namespace {

constexpr float kNearZ = 0.5f;       // metres; nothing of the world comes closer to the UAV
constexpr uint8_t kBackground = 96;  // beyond the edge of the world

struct Vertex {
  float sx, sy;    // pixel
  float inv_z;     // 1 / depth
  float u_z, v_z;  // texture metres / depth
  float shade_z;   // shade / depth
  bool valid;      // in front of the near plane
};

// Bilinear sample of one mip level at texel coordinates (u, v).
inline float SampleLevel(const cv::Mat& level, float u, float v, bool wrap_u) {
  const int cols = level.cols, rows = level.rows;
  u = std::max(u, 0.0f);
  v = std::clamp(v, 0.0f, static_cast<float>(rows - 1));
  int u0 = static_cast<int>(u);
  const int v0 = std::min(static_cast<int>(v), rows - 1);
  const float fu = u - u0, fv = v - v0;
  int u1 = u0 + 1;
  const int v1 = std::min(v0 + 1, rows - 1);
  if (wrap_u) {
    u0 %= cols;
    u1 %= cols;
  } else {
    u0 = std::min(u0, cols - 1);
    u1 = std::min(u1, cols - 1);
  }
  const uint8_t* r0 = level.ptr<uint8_t>(v0);
  const uint8_t* r1 = level.ptr<uint8_t>(v1);
  const float top = r0[u0] + fu * (r0[u1] - r0[u0]);
  const float bottom = r1[u0] + fu * (r1[u1] - r1[u0]);
  return top + fv * (bottom - top);
}

class Rasterizer {
 public:
  // `haze_per_m` (0: none): the ground fades towards the sky as exp(-haze_per_m * depth).
  Rasterizer(int width, int height, float haze_per_m) : width_(width), height_(height), haze_per_m_(haze_per_m) {
    color_ = cv::Mat(height, width, CV_8U, cv::Scalar(kBackground));
    inv_depth_ = cv::Mat(height, width, CV_32F, cv::Scalar(0.0f));
  }

  // Draws a triangle whose texture coordinates are in metres of `texture` (u wraps for facades).
  // `world_area_m2` sets the mip level: texels the triangle covers over pixels it covers.
  void Draw(const Vertex& a, const Vertex& b, const Vertex& c, const MipTexture& texture, double world_area_m2) {
    if (!a.valid || !b.valid || !c.valid) return;
    const float area = (b.sx - a.sx) * (c.sy - a.sy) - (b.sy - a.sy) * (c.sx - a.sx);
    // Counter-clockwise world triangles facing the camera have negative area in the image.
    if (!(area < -1e-6f)) return;
    const int x0 = std::max(0, static_cast<int>(std::ceil(std::min({a.sx, b.sx, c.sx}))));
    const int x1 = std::min(width_ - 1, static_cast<int>(std::floor(std::max({a.sx, b.sx, c.sx}))));
    const int y0 = std::max(0, static_cast<int>(std::ceil(std::min({a.sy, b.sy, c.sy}))));
    const int y1 = std::min(height_ - 1, static_cast<int>(std::floor(std::max({a.sy, b.sy, c.sy}))));
    if (x0 > x1 || y0 > y1) return;

    // Mip level from the ratio of texels to pixels the triangle covers (trilinear blend).
    const double texel_area = world_area_m2 / (texture.texel_m * texture.texel_m);
    const double lod = std::max(0.0, 0.5 * std::log2(std::max(1e-9, texel_area / (-0.5 * area))));
    const int max_level = static_cast<int>(texture.levels.size()) - 1;
    const int level0 = std::min(static_cast<int>(lod), max_level);
    const int level1 = std::min(level0 + 1, max_level);
    const float blend = static_cast<float>(std::min(1.0, lod - level0));
    const cv::Mat& tex0 = texture.levels[level0];
    const cv::Mat& tex1 = texture.levels[level1];
    const float scale0 = static_cast<float>(1.0 / (texture.texel_m * (1 << level0)));
    const float scale1 = static_cast<float>(1.0 / (texture.texel_m * (1 << level1)));
    // cv::pyrDown centres texel j of level k on texel 2^k j of level 0, so a level's texel
    // coordinate is the level-0 coordinate divided by 2^k, with no offset.

    const float inv_area = 1.0f / area;
    for (int y = y0; y <= y1; ++y) {
      const float py = static_cast<float>(y);
      uint8_t* color_row = color_.ptr<uint8_t>(y);
      float* depth_row = inv_depth_.ptr<float>(y);
      for (int x = x0; x <= x1; ++x) {
        const float px = static_cast<float>(x);
        // Barycentric weights (signed sub-areas / area); all >= 0 inside.
        const float wa = ((b.sx - px) * (c.sy - py) - (b.sy - py) * (c.sx - px)) * inv_area;
        const float wb = ((c.sx - px) * (a.sy - py) - (c.sy - py) * (a.sx - px)) * inv_area;
        const float wc = 1.0f - wa - wb;
        if (wa < 0 || wb < 0 || wc < 0) continue;
        const float inv_z = wa * a.inv_z + wb * b.inv_z + wc * c.inv_z;
        if (inv_z <= depth_row[x]) continue;
        depth_row[x] = inv_z;
        const float z = 1.0f / inv_z;
        const float u = (wa * a.u_z + wb * b.u_z + wc * c.u_z) * z;
        const float v = (wa * a.v_z + wb * b.v_z + wc * c.v_z) * z;
        const float shade = (wa * a.shade_z + wb * b.shade_z + wc * c.shade_z) * z;
        float value = SampleLevel(tex0, u * scale0, v * scale0, texture.wrap_u);
        if (blend > 0.01f && level1 != level0) {
          const float coarse = SampleLevel(tex1, u * scale1, v * scale1, texture.wrap_u);
          value += blend * (coarse - value);
        }
        float shaded = value * shade;
        if (haze_per_m_ > 0) shaded = kBackground + (shaded - kBackground) * std::exp(-haze_per_m_ * z);
        color_row[x] = static_cast<uint8_t>(std::clamp(shaded, 0.0f, 255.0f));
      }
    }
  }

  cv::Mat& color() { return color_; }
  cv::Mat& inv_depth() { return inv_depth_; }

 private:
  int width_, height_;
  float haze_per_m_;
  cv::Mat color_;
  cv::Mat inv_depth_;
};

}  // namespace

Renderer::Renderer(const SyntheticWorld& world, const Camera& camera)
    : world_(world), camera_(camera), canvas_(0, 0, camera.width(), camera.height()) {
  if (camera_.HasDistortion()) {
    // For each pixel of the distorted image, where it lies in the pinhole image; the pinhole
    // canvas is widened to hold every such place (a barrel lens sees past the pinhole image's
    // corners), within twice the image's size each way.
    const int w = camera_.width(), h = camera_.height();
    distort_map_x_.create(h, w, CV_32F);
    distort_map_y_.create(h, w, CV_32F);
    double x0 = 0, y0 = 0, x1 = w - 1, y1 = h - 1;
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        const Eigen::Vector2d p = camera_.UndistortPixel(Eigen::Vector2d(x, y));
        distort_map_x_.at<float>(y, x) = static_cast<float>(p.x());
        distort_map_y_.at<float>(y, x) = static_cast<float>(p.y());
        if (std::isfinite(p.x()) && std::isfinite(p.y())) {
          x0 = std::min(x0, p.x());
          x1 = std::max(x1, p.x());
          y0 = std::min(y0, p.y());
          y1 = std::max(y1, p.y());
        }
      }
    }
    const int left = static_cast<int>(std::floor(std::max(x0, -1.0 * w))) - 1;
    const int top = static_cast<int>(std::floor(std::max(y0, -1.0 * h))) - 1;
    const int right = static_cast<int>(std::ceil(std::min(x1, 2.0 * w))) + 2;
    const int bottom = static_cast<int>(std::ceil(std::min(y1, 2.0 * h))) + 2;
    canvas_ = cv::Rect(left, top, right - left, bottom - top);
    distort_map_x_ -= left;
    distort_map_y_ -= top;
  }
}

cv::Mat Renderer::Render(const Rigid3d& cam_from_world, cv::Mat* depth) const {
  cv::Mat pinhole = RenderPinhole(cam_from_world, depth);
  if (!camera_.HasDistortion()) return pinhole;
  cv::Mat distorted;
  cv::remap(pinhole, distorted, distort_map_x_, distort_map_y_, cv::INTER_LINEAR, cv::BORDER_CONSTANT,
            cv::Scalar(kBackground));
  return distorted;
}

cv::Mat Renderer::RenderPinhole(const Rigid3d& cam_from_world, cv::Mat* depth) const {
  const int width = canvas_.width, height = canvas_.height;
  // Koschmieder: contrast falls to 2% (ln 50 = 3.912) at the visibility distance.
  const double visibility = world_.options().visibility_m;
  Rasterizer raster(width, height, visibility > 0 ? static_cast<float>(3.912 / visibility) : 0.0f);
  const Eigen::Matrix3f r = cam_from_world.RotationMatrix().cast<float>();
  const Eigen::Vector3f t = cam_from_world.translation.cast<float>();
  const float fx = static_cast<float>(camera_.fx()), fy = static_cast<float>(camera_.fy());
  const float cx = static_cast<float>(camera_.cx() - canvas_.x), cy = static_cast<float>(camera_.cy() - canvas_.y);

  const auto make_vertex = [&](const Eigen::Vector3f& world_point, float tu, float tv, float shade) {
    const Eigen::Vector3f p = r * world_point + t;
    Vertex v;
    v.valid = p.z() > kNearZ;
    const float inv_z = v.valid ? 1.0f / p.z() : 0.0f;
    v.sx = fx * p.x() * inv_z + cx;
    v.sy = fy * p.y() * inv_z + cy;
    v.inv_z = inv_z;
    v.u_z = tu * inv_z;
    v.v_z = tv * inv_z;
    v.shade_z = shade * inv_z;
    return v;
  };

  // Visible part of the terrain grid: where the image corners' rays meet the lowest and highest
  // ground, widened by one cell.
  const Rigid3d world_from_cam = cam_from_world.Inverse();
  const Eigen::Vector3d centre = world_from_cam.translation;
  Eigen::Vector2d lo = Eigen::Vector2d::Constant(1e18), hi = Eigen::Vector2d::Constant(-1e18);
  bool unbounded = false;
  const double corners[4][2] = {{-0.5, -0.5}, {width - 0.5, -0.5}, {-0.5, height - 0.5}, {width - 0.5, height - 0.5}};
  for (const auto& corner : corners) {
    const Eigen::Vector3d ray =
        world_from_cam.rotation * Eigen::Vector3d((corner[0] - cx) / fx, (corner[1] - cy) / fy, 1.0);
    for (double ground : {world_.MinHeight(), world_.MaxHeight()}) {
      if (ray.z() >= -1e-6 || centre.z() <= ground) {
        unbounded = true;
        continue;
      }
      const Eigen::Vector3d hit = centre + ray * ((ground - centre.z()) / ray.z());
      lo = lo.cwiseMin(hit.head<2>());
      hi = hi.cwiseMax(hit.head<2>());
    }
  }
  if (unbounded) {  // looking at or above the horizon: draw everything
    lo = world_.min_xy();
    hi = world_.max_xy();
  }
  const double spacing = world_.spacing();
  const int c0 = std::max(0, static_cast<int>(std::floor((lo.x() - world_.min_xy().x()) / spacing)) - 1);
  const int c1 =
      std::min(world_.grid_cols() - 1, static_cast<int>(std::ceil((hi.x() - world_.min_xy().x()) / spacing)) + 1);
  const int r0 = std::max(0, static_cast<int>(std::floor((lo.y() - world_.min_xy().y()) / spacing)) - 1);
  const int r1 =
      std::min(world_.grid_rows() - 1, static_cast<int>(std::ceil((hi.y() - world_.min_xy().y()) / spacing)) + 1);

  if (c0 < c1 && r0 < r1) {
    const int cols = c1 - c0 + 1;
    std::vector<Vertex> row_below(cols), row_above(cols);
    const auto fill_row = [&](int row, std::vector<Vertex>* out) {
      for (int c = c0; c <= c1; ++c) {
        const Eigen::Vector3f p = world_.Vertex(c, row).cast<float>();
        (*out)[c - c0] = make_vertex(p, static_cast<float>(p.x() - world_.min_xy().x()),
                                     static_cast<float>(p.y() - world_.min_xy().y()), world_.VertexShade(c, row));
      }
    };
    fill_row(r0, &row_below);
    const double cell_area = 0.5 * spacing * spacing;
    for (int row = r0; row < r1; ++row) {
      fill_row(row + 1, &row_above);
      for (int k = 0; k + 1 < cols; ++k) {
        const Vertex& a = row_below[k];
        const Vertex& b = row_below[k + 1];
        const Vertex& c = row_above[k + 1];
        const Vertex& d = row_above[k];
        raster.Draw(a, b, c, world_.ground(), cell_area);
        raster.Draw(a, c, d, world_.ground(), cell_area);
      }
      std::swap(row_below, row_above);
    }
  }

  // Buildings: roof (ground texture, which carries the roof pattern) and walls (facade texture).
  for (const Building& building : world_.buildings()) {
    const double radius = std::hypot(building.half_length, building.half_width);
    if (building.centre.x() + radius < lo.x() - spacing || building.centre.x() - radius > hi.x() + spacing ||
        building.centre.y() + radius < lo.y() - spacing || building.centre.y() - radius > hi.y() + spacing) {
      continue;
    }
    const auto corners2d = building.Corners();
    const float top = static_cast<float>(building.base_z + building.height);
    const float bottom = static_cast<float>(building.base_z);
    Vertex roof[4];
    for (int k = 0; k < 4; ++k) {
      const Eigen::Vector3f p(static_cast<float>(corners2d[k].x()), static_cast<float>(corners2d[k].y()), top);
      roof[k] = make_vertex(p, static_cast<float>(p.x() - world_.min_xy().x()),
                            static_cast<float>(p.y() - world_.min_xy().y()), 1.0f);
    }
    const double roof_area = 2.0 * building.half_length * building.half_width;
    raster.Draw(roof[0], roof[1], roof[2], world_.ground(), roof_area);
    raster.Draw(roof[0], roof[2], roof[3], world_.ground(), roof_area);
    double along = building.facade_offset_m;
    for (int k = 0; k < 4; ++k) {
      const Eigen::Vector2d& p0 = corners2d[k];
      const Eigen::Vector2d& p1 = corners2d[(k + 1) % 4];
      const Eigen::Vector2d edge = p1 - p0;
      const double length = edge.norm();
      const float shade = building.wall_brightness * world_.WallShade(Eigen::Vector2d(edge.y(), -edge.x()));
      const float u0 = static_cast<float>(along), u1 = static_cast<float>(along + length);
      const float h = static_cast<float>(building.height);
      const Vertex b0 = make_vertex(Eigen::Vector3f(p0.x(), p0.y(), bottom), u0, 0.0f, shade);
      const Vertex b1 = make_vertex(Eigen::Vector3f(p1.x(), p1.y(), bottom), u1, 0.0f, shade);
      const Vertex t1 = make_vertex(Eigen::Vector3f(p1.x(), p1.y(), top), u1, h, shade);
      const Vertex t0 = make_vertex(Eigen::Vector3f(p0.x(), p0.y(), top), u0, h, shade);
      const double wall_area = 0.5 * length * building.height;
      raster.Draw(b0, b1, t1, world_.facade(), wall_area);
      raster.Draw(b0, t1, t0, world_.facade(), wall_area);
      along += length;
    }
  }

  if (depth) {
    depth->create(height, width, CV_32F);
    for (int y = 0; y < height; ++y) {
      const float* inv = raster.inv_depth().ptr<float>(y);
      float* out = depth->ptr<float>(y);
      for (int x = 0; x < width; ++x) out[x] = inv[x] > 0 ? 1.0f / inv[x] : 0.0f;
    }
  }
  return raster.color();
}

cv::Mat RenderOrthophoto(const SyntheticWorld& world, const cv::Size& size, double pixel_m,
                         const std::function<Eigen::Vector2d(int col, int row)>& world_at) {
  const MipTexture& texture = world.ground();
  const int max_level = static_cast<int>(texture.levels.size()) - 1;
  const int level =
      std::clamp(static_cast<int>(std::floor(std::log2(std::max(1.0, pixel_m / texture.texel_m)))), 0, max_level);
  const cv::Mat& texels = texture.levels[level];
  const double scale = 1.0 / (texture.texel_m * (1 << level));
  const double spacing = world.spacing();
  cv::Mat image(size, CV_8UC1, cv::Scalar(0));
  for (int row = 0; row < size.height; ++row) {
    uint8_t* out = image.ptr<uint8_t>(row);
    for (int col = 0; col < size.width; ++col) {
      const Eigen::Vector2d p = world_at(col, row);
      const Eigen::Vector2d local = p - world.min_xy();
      if (p.x() < world.min_xy().x() || p.y() < world.min_xy().y() || p.x() > world.max_xy().x() ||
          p.y() > world.max_xy().y()) {
        continue;
      }
      // Roofs are drawn unshaded; the terrain with its vertices' shade, across each cell.
      float shade = -1.0f;
      for (const Building& building : world.buildings()) {
        const Eigen::Vector2d d = p - building.centre;
        if (d.squaredNorm() > building.half_length * building.half_length + building.half_width * building.half_width) {
          continue;
        }
        const double c = std::cos(building.yaw), s = std::sin(building.yaw);
        if (std::abs(c * d.x() + s * d.y()) <= building.half_length &&
            std::abs(-s * d.x() + c * d.y()) <= building.half_width) {
          shade = 1.0f;
          break;
        }
      }
      if (shade < 0) {
        const double u = local.x() / spacing, v = local.y() / spacing;
        const int c0 = std::clamp(static_cast<int>(u), 0, world.grid_cols() - 2);
        const int r0 = std::clamp(static_cast<int>(v), 0, world.grid_rows() - 2);
        const float fu = static_cast<float>(u - c0), fv = static_cast<float>(v - r0);
        // The mesh's triangles (a, b, c) and (a, c, d) interpolate linearly within each.
        const float a = world.VertexShade(c0, r0), b = world.VertexShade(c0 + 1, r0);
        const float cc = world.VertexShade(c0 + 1, r0 + 1), d = world.VertexShade(c0, r0 + 1);
        shade = fu >= fv ? a + fu * (b - a) + fv * (cc - b) : a + fu * (cc - d) + fv * (d - a);
      }
      const float value =
          SampleLevel(texels, static_cast<float>(local.x() * scale), static_cast<float>(local.y() * scale), false) *
          shade;
      out[col] = static_cast<uint8_t>(std::clamp(value, 0.0f, 255.0f));
    }
  }
  return image;
}

}  // namespace stitch
