#include "tools/stitch/launch/run_mosaic.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <set>

#include <Eigen/Geometry>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "stitch/config/stitch_config.h"
#include "stitch/geometry/similarity.h"
#include "stitch/io/colmap_model.h"
#include "stitch/mosaic/checkpoints.h"
#include "stitch/mosaic/geotiff.h"
#include "stitch/mosaic/live_mosaic.h"
#include "stitch/mosaic/orthomosaic.h"
#include "stitch/records/keyframe_pictures.h"
#include "stitch/records/pose_record.h"
#include "stitch/records/run_info.h"
#include "stitch/synthetic/renderer.h"
#include "stitch/util/error.h"
#include "stitch/util/log.h"
#include "stitch/util/options.h"
#include "stitch/util/text_file.h"
#include "stitch/util/time.h"
#include "tools/stitch/launch/map_colours.h"
#include "tools/stitch/launch/run_images.h"

namespace fs = std::filesystem;

namespace stitch {
namespace {

Sim3d AsSim3(const Rigid3d& pose) {
  return Sim3d(1.0, pose.rotation, pose.translation);
}

// The mosaic's frame for a map placed on Earth: UTM easting and northing less `reference` (whole
// kilometres), and height, in metres. UTM is conformal: over a survey it is the ENU plane turned by
// the meridian convergence and scaled by the projection's scale factor, a similarity fitted here
// on points spread over the cameras' ground.
struct UtmFrame {
  UtmZone zone;
  Eigen::Vector2d reference = Eigen::Vector2d::Zero();
  Sim3d ground_from_enu;
};

UtmFrame UtmFrameOver(const GeodeticPoint& origin, const std::vector<Eigen::Vector3d>& centres_enu) {
  UtmFrame frame;
  frame.zone = UtmZoneOf(origin);
  const LocalTangentPlane plane(origin);
  Eigen::Vector2d lo = centres_enu.front().head<2>(), hi = lo;
  for (const Eigen::Vector3d& c : centres_enu) {
    lo = lo.cwiseMin(c.head<2>());
    hi = hi.cwiseMax(c.head<2>());
  }
  lo -= Eigen::Vector2d::Constant(200.0);
  hi += Eigen::Vector2d::Constant(200.0);
  const int n = 5;
  std::vector<Eigen::Vector2d> enu, utm;
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) {
      const Eigen::Vector2d p = lo + (hi - lo).cwiseProduct(Eigen::Vector2d(i, j) / (n - 1));
      enu.push_back(p);
      utm.push_back(ToUtm(plane.ToGeodetic(Eigen::Vector3d(p.x(), p.y(), 0.0)), frame.zone));
    }
  }
  const Similarity2d fit = FitSimilarity2d(enu, utm);
  const Eigen::Vector2d centre = ToUtm(origin, frame.zone);
  frame.reference = (centre / 1000.0).array().floor() * 1000.0;
  const Eigen::Vector2d shift = fit.shift - frame.reference;
  frame.ground_from_enu =
      Sim3d(fit.scale(), Eigen::Quaterniond(Eigen::AngleAxisd(fit.angle(), Eigen::Vector3d::UnitZ())),
            Eigen::Vector3d(shift.x(), shift.y(), 0.0));
  return frame;
}

}  // namespace

SourceSpec SourceOfRun(const std::string& run_dir) {
  const RunInfo info = LoadRunInfo(run_dir);
  SourceSpec spec;
  spec.dataset_path = info.dataset;
  // A live camera's run: its frames are gone once flown (only the pictures the ground received stay).
  if (spec.dataset_path.empty() && info.source.rfind("synthetic", 0) != 0) spec.live_uri = info.source;
  spec.start_frame = info.start_frame;
  spec.failures = info.failures.empty() ? "none" : info.failures;
  spec.max_frames = info.frames_total > 0 ? info.frames_total : -1;
  const fs::path config = fs::path(run_dir) / "config.yaml";
  if (fs::exists(config)) spec.synthetic = LoadStitchConfig(config.string()).synthetic;
  return spec;
}

std::optional<MapOnEarth> LargestMapOnEarth(const std::string& run_dir) {
  const fs::path path = fs::path(run_dir) / "geo" / "georeference.json";
  std::ifstream in(path);
  if (!in) return std::nullopt;
  try {
    const nlohmann::json json = nlohmann::json::parse(in);
    for (const nlohmann::json& map : json.at("maps")) {
      if (!map.value("largest", false) || !map.value("placed", false)) continue;
      MapOnEarth earth;
      const nlohmann::json& origin = json.at("origin");
      earth.origin = {origin.at("latitude_deg").get<double>(), origin.at("longitude_deg").get<double>(),
                      origin.at("height_m").get<double>()};
      const nlohmann::json& sim3 = map.at("enu_from_map");
      const auto q = sim3.at("rotation_xyzw").get<std::vector<double>>();
      const auto t = sim3.at("translation").get<std::vector<double>>();
      if (q.size() != 4 || t.size() != 3) throw Error("enu_from_map is not a similarity");
      earth.enu_from_map =
          Sim3d(sim3.at("scale").get<double>(), Eigen::Quaterniond(q[3], q[0], q[1], q[2]).normalized(),
                Eigen::Vector3d(t[0], t[1], t[2]));
      if (!(earth.enu_from_map.scale > 0) || !earth.enu_from_map.translation.allFinite() ||
          !WhyNotOnEarth(earth.origin).empty()) {
        throw Error("the largest map's placement is no place on Earth");
      }
      return earth;
    }
    return std::nullopt;
  } catch (const nlohmann::json::exception& e) {
    throw Error(path.string() + ": not the georeference stitch writes: " + e.what());
  } catch (const Error& e) {
    throw Error(path.string() + ": " + e.what());
  }
}

nlohmann::json RunMosaic::ToJson() const {
  nlohmann::json json = {{"file", path},
                         {"crs", crs},
                         {"on_earth", on_earth},
                         {"gsd", gsd},
                         {"units", on_earth ? "m" : "map units"},
                         {"pictures", pictures},
                         {"images", images},
                         {"width_px", width},
                         {"height_px", height},
                         {"area_covered", area},
                         {"cpu_ms_per_image", cpu_ms_per_image}};
  if (truth) {
    json["truth"] = {{"checkpoints", truth->checkpoints},
                     {"rms_gsd", truth->rms_gsd},
                     {"rms_after_similarity_gsd", truth->rms_after_similarity_gsd},
                     {"mean_offset_east_gsd", truth->mean_offset_gsd.x()},
                     {"mean_offset_north_gsd", truth->mean_offset_gsd.y()},
                     {"surveyed_area", truth->surveyed_area},
                     {"coverage", truth->coverage}};
  }
  return json;
}

std::vector<std::string> RunMosaic::Summary() const {
  std::vector<std::string> lines;
  char text[512];
  if (on_earth) {
    std::snprintf(text, sizeof(text), "  mosaic            %s: %d pictures, %dx%d px at %.3f m, %.2f ha covered, %s",
                  path.c_str(), images, width, height, gsd, area / 1e4, crs.c_str());
  } else {
    std::snprintf(text, sizeof(text), "  mosaic            %s: %d pictures, %dx%d px at %.4g map units a pixel (%s)",
                  path.c_str(), images, width, height, gsd, crs.c_str());
  }
  lines.push_back(text);
  if (truth) {
    std::snprintf(text, sizeof(text),
                  "    against the true orthophoto: %d checkpoints, %.2f GSD rms %s (%.2f after a 2D similarity); "
                  "%.1f%% of the surveyed area covered",
                  truth->checkpoints, truth->rms_gsd, on_earth ? "as placed on Earth" : "after the trajectory's Sim3",
                  truth->rms_after_similarity_gsd, 100.0 * truth->coverage);
    lines.push_back(text);
  }
  return lines;
}

MosaicPictures ParseMosaicPictures(const std::string& name) {
  if (name == "auto") return MosaicPictures::kAuto;
  if (name == "source") return MosaicPictures::kSource;
  if (name == "received") return MosaicPictures::kReceived;
  throw Error("pictures '" + name + "': give auto, source or received");
}

RunMosaic MakeRunMosaic(const std::string& run_dir, const SourceSpec& source, const MosaicOptions& options,
                        const std::string& out_path, MosaicPictures pictures) {
  CheckOptions(options, "mosaic");
  const fs::path model_dir = fs::path(run_dir) / "colmap";
  if (!fs::exists(model_dir / "images.txt")) {
    throw Error(run_dir +
                " has no colmap/ model (the merger writes one when it stops; a run whose merger wrote "
                "nothing has no map to lay images on)");
  }
  const ColmapModel model = ReadColmapModel(model_dir.string());
  if (model.images.empty()) throw Error(run_dir + "'s largest map has no keyframes");
  std::vector<Eigen::Vector3d> points, centres;
  for (const ColmapPoint& point : model.points) points.push_back(point.position);
  for (const ColmapImage& image : model.images) centres.push_back(image.cam_from_world.Inverse().translation);
  if (points.size() < 3) throw Error(run_dir + "'s largest map has too few points to shape the ground");
  if (const std::string why = WhyNotAGroundSeenFromAbove(points, centres, options); !why.empty()) {
    throw Error(run_dir + "'s largest map is not a ground seen from above: " + why +
                "; --force makes a mosaic of it anyway");
  }

  RunMosaic mosaic;
  mosaic.path = out_path;
  const std::optional<MapOnEarth> earth = LargestMapOnEarth(run_dir);
  Sim3d ground_from_map;
  Eigen::Vector2d reference = Eigen::Vector2d::Zero();  // the ground frame's origin in the CRS
  int epsg = 0;
  std::optional<Sim3d> ground_from_enu;
  if (earth) {
    std::vector<Eigen::Vector3d> centres_enu;
    for (const Eigen::Vector3d& c : centres) centres_enu.push_back(earth->enu_from_map * c);
    const UtmFrame utm = UtmFrameOver(earth->origin, centres_enu);
    ground_from_map = utm.ground_from_enu * earth->enu_from_map;
    ground_from_enu = utm.ground_from_enu;
    reference = utm.reference;
    epsg = utm.zone.epsg();
    mosaic.on_earth = true;
    mosaic.crs = "EPSG:" + std::to_string(epsg) + " (WGS 84 / UTM zone " + std::to_string(utm.zone.zone) +
                 (utm.zone.north ? "N" : "S") + ")";
  } else {
    ground_from_map = GroundFromMapByPlane(points, centres);
    mosaic.crs = "local: the largest map's frame levelled on its points' plane, in its units";
  }
  std::vector<Eigen::Vector3d> ground_points;
  for (const Eigen::Vector3d& p : points) ground_points.push_back(ground_from_map * p);

  // The pictures to lay: each with its frame, camera and pose in the ground's frame.
  struct View {
    int frame = 0;
    int camera_id = 1;
    Sim3d cam_from_map;
  };
  std::vector<View> views;
  const bool source_at_hand =
      !source.live_uri.empty() ? false : (source.synthetic_source() || fs::exists(source.dataset_path));
  const bool received = pictures == MosaicPictures::kReceived || (pictures == MosaicPictures::kAuto && !source_at_hand);
  const int camera_id = model.images.front().camera_id;
  if (received) {
    // The frames of the largest map (component 0, the model's) the ground has a picture of.
    std::set<int> pictured;
    for (const KeyframePicture& p : ReadKeyframePictureIndex(run_dir)) {
      if (p.agent == 0) pictured.insert(p.frame_index);
    }
    if (pictured.empty()) throw Error(run_dir + " holds no keyframe pictures the ground received (keyframe_images/)");
    for (const PoseRecord& pose : ReadPoseRecords((fs::path(run_dir) / "poses.tsv").string())) {
      if (pose.component == 0 && pictured.count(pose.frame_index)) {
        views.push_back({pose.frame_index, camera_id, AsSim3(pose.world_from_cam.Inverse())});
      }
    }
    if (views.empty()) throw Error("none of the pictures the ground received is of a frame of the largest map");
    mosaic.pictures = "the pictures the ground received";
  } else {
    for (const ColmapImage& image : model.images) {
      views.push_back({FrameOfModelImage(image), image.camera_id, AsSim3(image.cam_from_world)});
    }
    mosaic.pictures = "the flight's images";
  }
  std::map<int, const View*> view_of_frame;
  std::vector<int> frames;
  for (const View& view : views) {
    view_of_frame[view.frame] = &view;
    frames.push_back(view.frame);
  }
  const auto pose_of = [&](const View& view) { return view.cam_from_map * ground_from_map.Inverse(); };
  std::optional<Orthomosaic> ortho;
  MosaicGrid grid;
  double cpu_ms = 0;
  int done = 0, next_report = 1;
  const int total = static_cast<int>(views.size());
  const auto lay = [&](int frame, const cv::Mat& pixels) {
    const View& view = *view_of_frame.at(frame);
    Camera camera = model.cameras.at(view.camera_id);
    // The run may have worked at a reduced size, or the picture be one: the camera goes to its size.
    if (pixels.cols != camera.width() || pixels.rows != camera.height())
      camera = camera.Resized(pixels.cols, pixels.rows);
    if (!ortho) {
      // The pictures' own resolution, unless set: their median height above the ground over the focal length.
      grid.gsd = options.gsd_m;
      if (grid.gsd == 0) {
        std::vector<MosaicView> all;
        for (const View& other : views) all.push_back({&camera, pose_of(other)});
        const std::optional<double> gsd = MedianNadirGsd(all, ground_points);
        if (!gsd) throw Error("none of the map's cameras is above its ground: no mosaic of it can be made");
        grid.gsd = *gsd;
      }
      ortho.emplace(
          options, grid,
          GroundSurface::FromPoints(ground_points, options.surface_cell_gsd * grid.gsd, options.surface_min_points));
    }
    const double before = ThreadCpuMs();
    ortho->SetImage(frame, camera, pose_of(view), pixels);
    cpu_ms += ThreadCpuMs() - before;
    ++done;
    if (done * 4 >= next_report * total && next_report <= 4) {
      STITCH_LOG(INFO) << "mosaic: " << done << " of " << total << " pictures laid";
      ++next_report;
    }
  };
  if (received) {
    for (const int frame : frames) {
      const fs::path file = fs::path(run_dir) / "keyframe_images" / KeyframePictureName(0, frame);
      const cv::Mat pixels = cv::imread(file.string(), cv::IMREAD_UNCHANGED);
      if (pixels.empty()) throw Error(file.string() + ": not a readable picture");
      lay(frame, pixels);
    }
  } else {
    ReadRunImages(source, frames, lay);
  }
  if (!ortho) throw Error("no picture of the map could be laid");
  const MosaicRaster raster = ortho->Render();
  if (raster.colour.empty()) throw Error("no keyframe of the map sees its ground: the mosaic is empty");
  mosaic.gsd = grid.gsd;
  mosaic.images = total;
  mosaic.width = raster.colour.cols;
  mosaic.height = raster.colour.rows;
  mosaic.area = static_cast<double>(cv::countNonZero(raster.coverage)) * grid.gsd * grid.gsd;
  mosaic.cpu_ms_per_image = cpu_ms / std::max(1, total);

  GeoTiffImage tiff;
  tiff.colour = raster.colour;
  tiff.coverage = raster.coverage;
  tiff.pixel_size = grid.gsd;
  tiff.west = reference.x() + grid.origin.x() + raster.col0 * grid.gsd;
  tiff.north = reference.y() + grid.origin.y() - raster.row0 * grid.gsd;
  tiff.epsg = epsg;
  tiff.metadata["TIFFTAG_SOFTWARE"] = "stitch";
  tiff.metadata["STITCH_FRAME"] = mosaic.crs;
  tiff.metadata["STITCH_PICTURES"] = std::to_string(total) + " (" + mosaic.pictures + ")";
  tiff.metadata["STITCH_GSD"] = std::to_string(grid.gsd);
  WriteGeoTiff(out_path, tiff);

  // The synthetic flight: against the world's own orthophoto.
  if (source.synthetic_source()) {
    const auto flight = OpenSyntheticFlight(source);
    const SyntheticWorld& world = flight->world();
    // The synthetic world's frame is the ENU frame at the receiver's origin.
    const GeodeticPoint truth_origin{source.synthetic.gnss.origin_latitude_deg,
                                     source.synthetic.gnss.origin_longitude_deg, source.synthetic.gnss.origin_height_m};
    Sim3d world_from_ground;
    const bool same_origin = earth && std::abs(earth->origin.latitude_deg - truth_origin.latitude_deg) < 1e-9 &&
                             std::abs(earth->origin.longitude_deg - truth_origin.longitude_deg) < 1e-9 &&
                             std::abs(earth->origin.height_m - truth_origin.height_m) < 1e-6;
    if (same_origin) {
      world_from_ground = ground_from_enu->Inverse();
    } else {
      std::vector<Eigen::Vector3d> truth_centres;
      for (const ColmapImage& image : model.images) {
        truth_centres.push_back(
            flight->flight().WorldFromCam(source.start_frame + FrameOfModelImage(image)).translation);
      }
      world_from_ground = AlignPoints(centres, truth_centres) * ground_from_map.Inverse();
    }
    const double world_gsd = grid.gsd * world_from_ground.scale;
    const auto world_at = [&](double col, double row) {
      const Eigen::Vector2d g = grid.Ground(raster.col0 + col, raster.row0 + row);
      return Eigen::Vector2d(
          (world_from_ground * Eigen::Vector3d(g.x(), g.y(), ortho->surface().Height(g.x(), g.y()))).head<2>());
    };
    const cv::Mat truth =
        RenderOrthophoto(world, raster.colour.size(), world_gsd, [&](int col, int row) { return world_at(col, row); });
    const cv::Mat mask = raster.coverage & (truth > 0);
    const CheckpointErrors errors = MeasureCheckpoints(truth, raster.colour, mask);
    // Each checkpoint where it lies (in the mosaic's CRS) and how far off the mosaic has it.
    std::string csv = mosaic.on_earth ? "easting_m,northing_m,offset_east_m,offset_north_m,correlation\n"
                                      : "x,y,offset_x,offset_y,correlation\n";
    for (const CheckpointErrors::Checkpoint& p : errors.points) {
      const Eigen::Vector2d g = reference + grid.Ground(raster.col0 + p.at.x(), raster.row0 + p.at.y());
      char line[160];
      std::snprintf(line, sizeof(line), "%.3f,%.3f,%.3f,%.3f,%.3f\n", g.x(), g.y(), p.offset.x() * grid.gsd,
                    -p.offset.y() * grid.gsd, p.correlation);
      csv += line;
    }
    WriteFileAtomically(fs::path(out_path).replace_extension(".checkpoints.csv").string(), csv);
    RunMosaic::Truth t;
    t.checkpoints = errors.checkpoints;
    t.rms_gsd = errors.rms_px;
    t.rms_after_similarity_gsd = errors.rms_after_similarity_px;
    t.mean_offset_gsd = Eigen::Vector2d(errors.mean_offset_px.x(), -errors.mean_offset_px.y());
    // The surveyed area: the planned flight's footprints (gust frames left out), each image's
    // rays held within the off-nadir cone, on a grid of 4 GSD in the world.
    const int played = source.max_frames > 0 ? std::min(source.max_frames, flight->size() - source.start_frame)
                                             : flight->size() - source.start_frame;
    const Camera& camera = flight->camera();
    const double max_angle = options.max_off_nadir_deg * M_PI / 180.0;
    std::vector<std::vector<cv::Point2d>> footprints;
    Eigen::Vector2d lo = Eigen::Vector2d::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
    for (int f = source.start_frame; f < source.start_frame + played; ++f) {
      if (flight->flight().InGust(f)) continue;
      const Rigid3d world_from_cam = flight->flight().WorldFromCam(f);
      const Eigen::Vector3d& c = world_from_cam.translation;
      const double ground_z = world.TerrainHeight(c.x(), c.y());
      if (c.z() <= ground_z) continue;
      std::vector<cv::Point2d> corners;
      for (const Eigen::Vector2d& pixel :
           {Eigen::Vector2d(0, 0), Eigen::Vector2d(camera.width() - 1, 0),
            Eigen::Vector2d(camera.width() - 1, camera.height() - 1), Eigen::Vector2d(0, camera.height() - 1)}) {
        const Eigen::Vector3d ray = WithinOffNadirCone(world_from_cam.rotation * camera.PixelToRay(pixel), max_angle);
        if (ray.z() >= 0) continue;
        const Eigen::Vector3d hit = c + ray * ((ground_z - c.z()) / ray.z());
        corners.emplace_back(hit.x(), hit.y());
        lo = lo.cwiseMin(hit.head<2>());
        hi = hi.cwiseMax(hit.head<2>());
      }
      footprints.push_back(std::move(corners));
    }
    if (!footprints.empty()) {
      const double cell = 4.0 * world_gsd;
      const int cols = static_cast<int>(std::ceil((hi.x() - lo.x()) / cell)) + 1;
      const int rows = static_cast<int>(std::ceil((hi.y() - lo.y()) / cell)) + 1;
      if (static_cast<double>(cols) * rows <= 1e8) {
        cv::Mat surveyed(rows, cols, CV_8UC1, cv::Scalar(0));
        for (const auto& corners : footprints) {
          std::vector<cv::Point> polygon;
          for (const cv::Point2d& p : corners) {
            polygon.emplace_back(static_cast<int>(std::lround((p.x - lo.x()) / cell)),
                                 static_cast<int>(std::lround((p.y - lo.y()) / cell)));
          }
          cv::fillConvexPoly(surveyed, polygon, cv::Scalar(255));
        }
        const Sim3d ground_from_world = world_from_ground.Inverse();
        int64_t inside = 0, covered = 0;
        for (int r = 0; r < rows; ++r) {
          for (int c = 0; c < cols; ++c) {
            if (!surveyed.at<uchar>(r, c)) continue;
            ++inside;
            const double x = lo.x() + c * cell, y = lo.y() + r * cell;
            const Eigen::Vector3d g = ground_from_world * Eigen::Vector3d(x, y, world.TerrainHeight(x, y));
            const Eigen::Vector2d p = grid.Pixel(g.head<2>());
            const int col = static_cast<int>(std::lround(p.x())) - raster.col0;
            const int row = static_cast<int>(std::lround(p.y())) - raster.row0;
            if (col >= 0 && row >= 0 && col < raster.coverage.cols && row < raster.coverage.rows &&
                raster.coverage.at<uchar>(row, col)) {
              ++covered;
            }
          }
        }
        t.surveyed_area = inside * cell * cell;
        t.coverage = inside > 0 ? static_cast<double>(covered) / inside : 0.0;
      }
    }
    mosaic.truth = t;
  }
  return mosaic;
}

}  // namespace stitch
