// `stitch run` end to end: the real service processes over UDP multicast.

#include <arpa/inet.h>
#include <signal.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <regex>
#include <set>
#include <sstream>
#include <thread>
#include <tuple>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/videoio.hpp>

#include "services/common/bus.h"
#include "stitch/geo/exiv2.h"
#include "stitch/geo/geodetic.h"
#include "stitch/geo/geoid.h"
#include "stitch/geo/gnss_fix.h"
#include "stitch/geo/mavlink_gnss.h"
#include "stitch/gnss_fix_t.hpp"
#include "stitch/io/calibration.h"
#include "stitch/io/colmap_model.h"
#include "stitch/io/image_sequence.h"
#include "stitch/io/ply.h"
#include "stitch/io/trajectory.h"
#include "stitch/mosaic/geotiff.h"
#include "stitch/records/frame_record.h"
#include "stitch/records/keyframe_pictures.h"
#include "stitch/records/merger_records.h"
#include "stitch/testing/full_disk.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/child_process.h"
#include "stitch/util/text_file.h"
#include "stitch/util/time.h"
#include "tests/test_process.h"

namespace fs = std::filesystem;

namespace stitch {
namespace {

using testing::Bin;
using testing::RunProgram;

using testing::ReadJson;
const std::string kShortFlight = testing::ShortFlightConfig();

STITCH_EXIV2_BEGIN
// Writes `position` into `jpeg`'s EXIF GPS tags as a survey camera does (degrees, minutes and
// seconds as rationals; the altitude in millimetres).
void WriteExifGps(const std::string& jpeg, const GeodeticPoint& position) {
  const auto dms = [](double degrees) {
    degrees = std::abs(degrees);
    const int whole = static_cast<int>(degrees);
    const double minutes = (degrees - whole) * 60;
    const int whole_minutes = static_cast<int>(minutes);
    const long centiseconds = std::lround((minutes - whole_minutes) * 60 * 10000);
    return std::to_string(whole) + "/1 " + std::to_string(whole_minutes) + "/1 " + std::to_string(centiseconds) +
           "/10000";
  };
  Exiv2::Image::AutoPtr image = Exiv2::ImageFactory::open(jpeg);
  image->readMetadata();
  Exiv2::ExifData& exif = image->exifData();
  exif["Exif.GPSInfo.GPSLatitudeRef"] = position.latitude_deg >= 0 ? "N" : "S";
  exif["Exif.GPSInfo.GPSLatitude"] = dms(position.latitude_deg);
  exif["Exif.GPSInfo.GPSLongitudeRef"] = position.longitude_deg >= 0 ? "E" : "W";
  exif["Exif.GPSInfo.GPSLongitude"] = dms(position.longitude_deg);
  exif["Exif.GPSInfo.GPSAltitudeRef"] = position.height_m >= 0 ? "0" : "1";
  exif["Exif.GPSInfo.GPSAltitude"] = std::to_string(std::lround(std::abs(position.height_m) * 1000)) + "/1000";
  image->writeMetadata();
}
STITCH_EXIV2_END

// `stitch render` of the short flight's first `frames` frames into the folder `images`, with its
// gusts unless `failures` says otherwise.
testing::CommandResult RenderShortFlight(const std::string& images, int frames,
                                         const std::string& failures = "default") {
  return RunProgram({Bin("stitch"), "render", "--config", kShortFlight, "--out", images, "--failures", failures,
                     "--max-frames", std::to_string(frames)},
                    60);
}

// The images `stitch render` wrote to `folder` (named by their time in seconds), in time order.
std::vector<fs::path> RenderedImagesInTimeOrder(const std::string& folder) {
  std::vector<fs::path> images;
  for (const auto& entry : fs::directory_iterator(folder)) {
    if (entry.path().extension() == ".png") images.push_back(entry.path());
  }
  std::sort(images.begin(), images.end(),
            [](const fs::path& a, const fs::path& b) { return std::stod(a.stem()) < std::stod(b.stem()); });
  return images;
}

TEST(StitchRun, TracksAShortFlightWithTheServicesAsProcesses) {
  testing::TempDir dir;
  const std::string out = dir / "run";
  // Its 60 frames make fewer keyframes than the live mosaic waits for by default (10 pictures).
  const auto result = RunProgram({Bin("stitch"), "run", "--config", kShortFlight, "--out", out, "--failures", "none",
                                  "--set", "merger.mosaic.live_min_pictures=3"},
                                 180);
  ASSERT_EQ(result.exit_code, 0) << result.output;
  for (const char* file :
       {"trajectory.tum",   "map.ply",         "report.json",     "trajectory.png",  "frames.tsv",
        "poses.tsv",        "keyframes.tsv",   "groundtruth.tum", "config.yaml",     "run.json",
        "logs/tracker.log", "logs/ingest.log", "logs/mapper.log", "logs/merger.log", "submaps.tsv",
        "graph.dot",        "graph.png",       "merge_log.tsv",   "retrieval.tsv",   "keyframes_merged.tsv",
        "memory.tsv",       "map.stitchmap"}) {
    EXPECT_TRUE(fs::exists(fs::path(out) / file)) << file;
  }
  // The map saved for a later flight (#44): read back and written again, the same bytes.
  const auto saved = RunProgram({Bin("stitch"), "map", "save", out, "--out", dir / "site.stitchmap"}, 60);
  ASSERT_EQ(saved.exit_code, 0) << saved.output;
  EXPECT_EQ(ReadFileBytes(dir / "site.stitchmap"), ReadFileBytes(out + "/map.stitchmap"));
  const auto info = RunProgram({Bin("stitch"), "map", "info", dir / "site.stitchmap"}, 60);
  ASSERT_EQ(info.exit_code, 0) << info.output;
  EXPECT_NE(info.output.find("format version 1"), std::string::npos) << info.output;
  // Each service's memory: sampled during the flight, its peak once it ended.
  std::ifstream memory(out + "/memory.tsv");
  std::string header, first;
  std::getline(memory, header);
  std::getline(memory, first);
  EXPECT_EQ(header, "seconds\tframe\tservice\trss_mb");
  EXPECT_FALSE(first.empty()) << "no sample";
  const auto peaks = ReadJson(out + "/run.json")["peak_rss_mb"];
  for (const char* service : {"ingest", "tracker", "mapper", "merger"}) {
    ASSERT_TRUE(peaks.contains(service)) << service;
    EXPECT_GT(peaks[service].get<double>(), 10.0) << service;
  }
  EXPECT_NE(result.output.find("peak memory"), std::string::npos) << result.output;
  const auto report = ReadJson(out + "/report.json");
  for (const char* key : {"frames_total", "frames_localized", "completeness", "keyframes", "submaps", "submaps_merged",
                          "ate_rmse_m", "tracking_ms_median"}) {
    EXPECT_TRUE(report.contains(key)) << key;
  }
  EXPECT_EQ(report["frames_total"], 60);
  // Every frame went through ingest, the bus and the tracker process, once.
  const auto records = ReadFrameRecords(out + "/frames.tsv");
  ASSERT_EQ(records.size(), 60u);
  for (int i = 0; i < 60; ++i) EXPECT_EQ(records[i].frame_index, i);
  EXPECT_EQ(Trajectory::ReadTum(out + "/groundtruth.tum").size(), 60u);
  // The trajectory agrees with the ground truth: all but the first frames posed, ATE well under
  // 1% of the 69 m strip.
  EXPECT_GE(report["frames_localized"].get<int>(), 56) << result.output;
  ASSERT_FALSE(report["ate_rmse_m"].is_null());
  EXPECT_LT(report["ate_rmse_m"].get<double>(), 0.3);
  EXPECT_GT(report["keyframes"].get<int>(), 3);
  // The mapper's map made it to disk.
  EXPECT_GT(ReadPly(out + "/map.ply").size(), 500u);
  // The summary says what happened.
  EXPECT_NE(result.output.find("frames localized"), std::string::npos) << result.output;
  // `stitch eval` rebuilds the same report from the folder.
  const auto eval = RunProgram({Bin("stitch"), "eval", out});
  EXPECT_EQ(eval.exit_code, 0) << eval.output;
  EXPECT_EQ(ReadJson(out + "/report.json")["frames_total"], 60);
  // The strip's orthomosaic: placed on Earth by the synthetic receiver's fixes, north up in UTM
  // zone 32 (the world is at 48 N, 11 E), the flight's keyframes rendered again and laid on it.
  const std::string ortho = dir / "ortho.tif";
  // A map whose relief is above merger.mosaic.live_max_relief (here set below the strip's own) is no
  // ground seen from above: refused, saying so, unless --force.
  const std::vector<std::string> strict = {"--set", "merger.mosaic.live_max_relief=0.001"};
  const auto refused =
      RunProgram({Bin("stitch"), "mosaic", out, "--out", dir / "refused.tif", strict[0], strict[1]}, 120);
  EXPECT_EQ(refused.exit_code, 1) << refused.output;
  EXPECT_NE(refused.output.find("is not a ground seen from above"), std::string::npos) << refused.output;
  EXPECT_FALSE(fs::exists(dir / "refused.tif"));
  const auto forced =
      RunProgram({Bin("stitch"), "mosaic", out, "--out", dir / "forced.tif", strict[0], strict[1], "--force"}, 120);
  EXPECT_EQ(forced.exit_code, 0) << forced.output;
  const auto mosaic = RunProgram({Bin("stitch"), "mosaic", out, "--out", ortho}, 120);
  ASSERT_EQ(mosaic.exit_code, 0) << mosaic.output;
  const GeoTiffInfo tiff = ReadGeoTiffInfo(ortho);
  EXPECT_EQ(tiff.epsg, 32632);
  EXPECT_EQ(tiff.bands, 4);
  EXPECT_NEAR(tiff.geo_transform[1], 0.15, 0.03);  // 70 m up, a 450 px focal length
  const auto figures = ReadJson(dir / "ortho.json");
  EXPECT_EQ(figures["on_earth"], true);
  EXPECT_EQ(figures["images"].get<size_t>(), ReadColmapModel(out + "/colmap").images.size()) << figures.dump();
  // Against the world's true orthophoto: where the strip is, and its shape.
  ASSERT_TRUE(figures.contains("truth")) << figures.dump();
  EXPECT_GT(figures["truth"]["checkpoints"].get<int>(), 100) << figures.dump();
  EXPECT_LT(figures["truth"]["rms_after_similarity_gsd"].get<double>(), 3.0) << figures.dump();
  EXPECT_GT(figures["truth"]["coverage"].get<double>(), 0.9) << figures.dump();
  // gdalinfo, not ours, reads it with its CRS and place.
  if (testing::OnPath("gdalinfo")) {
    const auto info = RunProgram({"/usr/bin/env", "gdalinfo", ortho}, 30);
    EXPECT_EQ(info.exit_code, 0) << info.output;
    EXPECT_NE(info.output.find("WGS 84 / UTM zone 32N"), std::string::npos) << info.output;
    EXPECT_NE(info.output.find("Band 4 Block=256x256 Type=Byte, ColorInterp=Alpha"), std::string::npos) << info.output;
    EXPECT_NE(info.output.find("Overviews"), std::string::npos) << info.output;
  }
  // The merger kept its own during the flight from the pictures it received, on Earth where the
  // fixes placed the map during the flight: east and north of the first fix (an orthographic
  // projection there), where the final one lies and as large, in metres.
  const GeoTiffInfo live = ReadGeoTiffInfo(out + "/mosaic_live.tif");
  EXPECT_EQ(live.bands, 4);
  EXPECT_GT(live.width, 100);
  ASSERT_NE(live.crs.find("+proj=ortho"), std::string::npos) << live.crs;
  const auto parameter = [&live](const std::string& name) {
    return std::stod(live.crs.substr(live.crs.find("+" + name + "=") + name.size() + 2));
  };
  const LocalTangentPlane first_fix({parameter("lat_0"), parameter("lon_0"), 0.0});
  const auto centre = [](const GeoTiffInfo& info) {
    const double* t = info.geo_transform;
    return Eigen::Vector3d(t[0] + 0.5 * info.width * t[1], t[3] + 0.5 * info.height * t[5], 0.0);
  };
  const Eigen::Vector2d live_centre = ToUtm(first_fix.ToGeodetic(centre(live)), UtmZone{32, true});
  EXPECT_LT((live_centre - centre(tiff).head<2>()).norm(), 8.0) << "the 69 m strip's mosaics lie apart";
  EXPECT_NEAR(live.width * live.geo_transform[1] / (tiff.width * tiff.geo_transform[1]), 1.0, 0.3);
  EXPECT_EQ(live.metadata.at("STITCH_FRAME"), "the maps the GNSS fixes place, east and north of the first fix, metres");
  // The same from the reduced pictures the aircraft sent down (what the ground has of a live camera).
  const size_t pictures = ReadKeyframePictureIndex(out).size();
  EXPECT_GE(pictures, 3u);
  const auto from_pictures =
      RunProgram({Bin("stitch"), "mosaic", out, "--pictures", "received", "--out", dir / "received.tif"}, 120);
  ASSERT_EQ(from_pictures.exit_code, 0) << from_pictures.output;
  const auto received = ReadJson(dir / "received.json");
  EXPECT_EQ(received["pictures"], "the pictures the ground received");
  EXPECT_LE(received["images"].get<size_t>(), pictures);
  EXPECT_GT(received["truth"]["coverage"].get<double>(), 0.8) << received.dump();
  // Refused: a folder that is no run.
  EXPECT_NE(RunProgram({Bin("stitch"), "mosaic", dir / "nothing"}, 30).exit_code, 0);
}

// The live mosaic's cost guard stops it (here at any cost), and what it drew stays: its file,
// written at the end of the flight with the pictures it laid.
TEST(StitchRun, ALiveMosaicStoppedForItsCostKeepsWhatItDrew) {
  testing::TempDir dir;
  const std::string out = dir / "run";
  // A strip of 200 frames: its mosaic lays over the 8 pictures the guard waits for.
  const auto result = RunProgram({Bin("stitch"), "run", "--out", out, "--failures", "none", "--set",
                                  "synthetic.flight.num_frames=200", "--set", "synthetic.flight.num_strips=1", "--set",
                                  "synthetic.flight.strip_length_m=230", "--set", "merger.mosaic.live_min_pictures=3",
                                  "--set", "merger.mosaic.live_max_cpu_ms_per_picture=0.001"},
                                 180);
  ASSERT_EQ(result.exit_code, 0) << result.output;
  const std::string log = ReadFileBytes(out + "/logs/merger.log");
  std::smatch stopped;
  ASSERT_TRUE(std::regex_search(log, stopped, std::regex("the live mosaic stopped with ([0-9]+) pictures drawn")))
      << log;
  ASSERT_TRUE(fs::exists(out + "/mosaic_live.tif")) << log;
  const GeoTiffInfo live = ReadGeoTiffInfo(out + "/mosaic_live.tif");
  // Every picture drawn when it stopped, those of the update that stopped it too.
  EXPECT_EQ(live.metadata.at("STITCH_PICTURES"), stopped[1].str());
  EXPECT_GE(std::stoi(stopped[1].str()), 3);
  EXPECT_GT(live.width, 100);
}

TEST(StitchRun, CtrlCStopsEverythingAndStillWritesTheOutputs) {
  testing::TempDir dir;
  const std::string out = dir / "run";
  std::ofstream(dir / "long.yaml") << "synthetic:\n  flight:\n    num_frames: 100000\n    num_strips: 1\n"
                                      "    strip_length_m: 60\n  world:\n    num_buildings: 4\n";
  // Ctrl-C 4 s into the flight: after the run has said where its outputs go, its set-up done.
  const auto result =
      RunProgram({Bin("stitch"), "run", "--config", dir / "long.yaml", "--out", out}, 90, 4, SIGINT, "  output ");
  EXPECT_EQ(result.exit_code, 130) << result.output;
  EXPECT_TRUE(fs::exists(out + "/report.json")) << result.output;
  EXPECT_EQ(ReadJson(out + "/run.json")["interrupted"], true);
  // No service is left running on this run's bus.
  const auto leftover = RunProgram({"/usr/bin/pgrep", "-f", "--", "--record " + out + "/frames.tsv"});
  EXPECT_NE(leftover.exit_code, 0) << "a tracker survived:\n" << leftover.output;
}

TEST(StitchRun, BadInputsGiveAClearErrorAndANonZeroExit) {
  testing::TempDir dir;
  struct Case {
    std::vector<std::string> args;
    std::string expected;
  };
  std::ofstream(dir / "typo.yaml") << "ingest:\n  pacnig: realtime\n";
  std::ofstream(dir / "calib.yaml")
      << "Camera.fx: 500\nCamera.fy: 500\nCamera.cx: 320\nCamera.cy: 240\nCamera.width: 752\nCamera.height: 480\n";
  fs::create_directories(dir.path() / "images");
  std::ofstream(dir / "images/0.png") << "not a png";
  std::ofstream(dir / "cut.stitchmap") << "STITCHMP\x01";
  const std::vector<Case> cases = {
      {{Bin("stitch"), "run", "--dataset", dir / "missing"}, "no such file or folder"},
      {{Bin("stitch"), "run", "--config", dir / "typo.yaml"}, "pacnig"},
      {{Bin("stitch"), "run", "--config", dir / "nothere.yaml"}, "no such file"},
      {{Bin("stitch"), "run", "--failures", "12:x"}, "FRAME:LENGTH"},
      {{Bin("stitch"), "run", "--on-loss", "panic"}, "on_loss"},
      {{Bin("stitch"), "run", "--dataset", dir / "images", "--calib", dir / "calib.yaml"}, "first image"},
      {{Bin("stitch"), "run", "--bogus"}, "unknown option"},
      {{Bin("stitch"), "eval"}, "nothing to evaluate"},
      {{Bin("stitch"), "eval", dir.path().string()}, "run.json"},
      {{Bin("stitch"), "eval", "--est", dir / "calib.yaml", "--absolute"}, "--absolute needs --gt"},
      {{Bin("stitch"), "eval", "--est", dir / "calib.yaml", "--origin", "48,11,600"}, "--origin goes with --absolute"},
      {{Bin("stitch"), "eval", "--est", dir / "calib.yaml", "--gt", dir / "calib.yaml", "--absolute", "--origin",
        "95,11,0"},
       "latitude 95"},
      {{Bin("stitch"), "frobnicate"}, "unknown command"},
      {{Bin("stitch-ingest"), "--pacing", "warp"}, "pacing"},
      {{Bin("stitch-ingest"), "--agent", "uav 0"}, "agent name"},
      {{Bin("stitch-tracker"), "--config", dir / "typo.yaml"}, "pacnig"},
      {{Bin("stitch-link"), "--peer", "nowhere"}, "ADDRESS:PORT"},
      {{Bin("stitch-link"), "--loss", "2"}, "link.loss"},
      {{Bin("stitch"), "run", "--link-loss", "0.1"}, "need --link"},
      {{Bin("stitch"), "run", "--vocabulary", dir / "ORBvoc.txt"}, "no such vocabulary file"},
      {{Bin("stitch"), "run", "--start-frame", "-3"}, "--start-frame must be >= 0"},
      {{Bin("stitch"), "run", "--live", "flight.mp4", "--calib", dir / "calib.yaml"}, "GStreamer pipeline"},
      {{Bin("stitch"), "run", "--live", "/dev/video0"}, "--calib"},
      {{Bin("stitch"), "run", "--map", dir / "nothere.stitchmap"}, "cannot open"},
      {{Bin("stitch"), "run", "--localize-only"}, "--localize-only needs --map"},
      {{Bin("stitch-tracker"), "--set", "tracker.tracking.localize_only=true"}, "needs a prior_map"},
      {{Bin("stitch"), "run", "--map", dir / "calib.yaml"}, "not a stitch map"},
      {{Bin("stitch"), "map", "info", dir / "cut.stitchmap"}, "not a stitch map"},
      {{Bin("stitch"), "map", "save", dir.path().string(), "--out", dir / "x.stitchmap"}, "holds no map.stitchmap"},
      {{Bin("stitch-ingest"), "--live", "/dev/video-none", "--calib", dir / "calib.yaml", "--lcm-url", "memq://",
        "--set", "ingest.wait_for_tracker_s=0"},
       "cannot open it"},
  };
  for (const auto& c : cases) {
    const auto result = RunProgram(c.args, 30);
    std::string line;
    for (const auto& a : c.args) line += a + " ";
    EXPECT_NE(result.exit_code, 0) << line << "\n" << result.output;
    EXPECT_NE(result.exit_code, 128 + SIGSEGV) << line;
    EXPECT_NE(result.output.find(c.expected), std::string::npos) << line << "\nsaid:\n" << result.output;
  }
}

TEST(StitchRun, EveryCommandHasHelp) {
  for (const std::vector<std::string>& args :
       std::vector<std::vector<std::string>>{{Bin("stitch"), "--help"},
                                             {Bin("stitch"), "run", "--help"},
                                             {Bin("stitch"), "eval", "--help"},
                                             {Bin("stitch"), "render", "--help"},
                                             {Bin("stitch"), "config", "--help"},
                                             {Bin("stitch"), "merger", "--help"},
                                             {Bin("stitch"), "spy", "--help"},
                                             {Bin("stitch"), "export", "--help"},
                                             {Bin("stitch"), "mosaic", "--help"},
                                             {Bin("stitch"), "map", "save", "--help"},
                                             {Bin("stitch"), "map", "info", "--help"},
                                             {Bin("stitch-ingest"), "--help"},
                                             {Bin("stitch-tracker"), "--help"},
                                             {Bin("stitch"), "link", "--help"},
                                             {Bin("stitch-link"), "--help"}}) {
    const auto result = RunProgram(args, 10);
    EXPECT_EQ(result.exit_code, 0) << args[0] << " " << args[1];
    EXPECT_NE(result.output.find("usage:"), std::string::npos) << result.output;
  }
}

TEST(StitchRender, WritesAFolderThatRunsAsADataset) {
  testing::TempDir dir;
  const std::string images = dir / "flight";
  const auto render = RenderShortFlight(images, 12);
  ASSERT_EQ(render.exit_code, 0) << render.output;
  EXPECT_TRUE(fs::exists(images + "/camera.yaml"));
  EXPECT_EQ(Trajectory::ReadTum(images + "/groundtruth.txt").size(), 12u);
  // As an ORB-SLAM user would run it: their settings file as it is (ORB-SLAM2's `key:value`
  // without a space, ORBextractor.*), a vocabulary named on the command line, a start frame.
  {
    std::ifstream camera(images + "/camera.yaml");
    std::ofstream(dir / "orbslam.yaml") << camera.rdbuf() << "ORBextractor.nFeatures: 800\nViewer.PointSize:2\n";
  }
  // One image damaged on disk: played as unreadable, counted in the report and the summary.
  const std::vector<fs::path> pngs = RenderedImagesInTimeOrder(images);
  ASSERT_EQ(pngs.size(), 12u);
  std::ofstream(pngs[7]) << "not a png any more";
  const std::string vocabulary = std::string(STITCH_SOURCE_DIR) + "/vocabulary/default.stitchvoc";
  const auto run = RunProgram({Bin("stitch"), "run", "--dataset", images, "--out", dir / "run", "--calib",
                               dir / "orbslam.yaml", "--vocabulary", vocabulary, "--start-frame", "2"},
                              60);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_EQ(ReadJson(dir / "run/report.json")["frames_total"], 10);
  EXPECT_EQ(ReadJson(dir / "run/report.json")["frames_unreadable"], 1);
  EXPECT_NE(run.output.find("1 frames could not be read"), std::string::npos) << run.output;
  EXPECT_EQ(ReadJson(dir / "run/report.json")["has_ground_truth"], true);
  // The ground truth of the frames played, and the sample before them (to interpolate at the start).
  EXPECT_EQ(Trajectory::ReadTum(dir / "run/groundtruth.tum").size(), 11u);
  EXPECT_NE(run.output.find("tracker.tracking.orb.num_features=800"), std::string::npos) << run.output;
  std::stringstream config, tracker_log;
  config << std::ifstream(dir / "run/config.yaml").rdbuf();
  EXPECT_NE(config.str().find("num_features: 800"), std::string::npos);
  tracker_log << std::ifstream(dir / "run/logs/tracker.log").rdbuf();
  EXPECT_NE(tracker_log.str().find("vocabulary " + vocabulary), std::string::npos) << tracker_log.str();
}

// A KITTI odometry sequence (the short flight laid out as KITTI ships one) gives its trajectory
// in KITTI's format, in the ground truth's frame, with each line's frame number; every map has
// its own TUM file under trajectories/.
TEST(StitchRun, AKittiSequenceGivesItsTrajectoryInKittiFormatAndEveryMapItsOwnFile) {
  testing::TempDir dir;
  const std::string images = dir / "flight";
  const auto render = RenderShortFlight(images, 40, "none");
  ASSERT_EQ(render.exit_code, 0) << render.output;
  const Trajectory truth = Trajectory::ReadTum(images + "/groundtruth.txt");
  ASSERT_EQ(truth.size(), 40u);
  const fs::path sequence = dir.path() / "kitti" / "sequences" / "03";
  fs::create_directories(sequence / "image_0");
  fs::create_directories(dir.path() / "kitti" / "poses");
  std::ofstream times(sequence / "times.txt"), poses(dir.path() / "kitti" / "poses" / "03.txt");
  poses.precision(10);
  for (size_t i = 0; i < truth.size(); ++i) {
    const StampedPose& p = truth.poses()[i];
    char name[32], stamp[32];
    std::snprintf(name, sizeof(name), "%06zu.png", i);
    std::snprintf(stamp, sizeof(stamp), "%.9f", p.t_ns * 1e-9);
    fs::rename(images + "/" + stamp + ".png", sequence / "image_0" / name);
    times << stamp << "\n";
    const Eigen::Matrix3d r = p.world_from_cam.rotation.toRotationMatrix();
    for (int row = 0; row < 3; ++row) {
      poses << r(row, 0) << " " << r(row, 1) << " " << r(row, 2) << " " << p.world_from_cam.translation[row]
            << (row == 2 ? "\n" : " ");
    }
  }
  times.close();
  poses.close();
  std::ofstream(sequence / "calib.txt") << "P0: 450 0 319.5 0 0 450 239.5 0 0 0 1 0\n";
  const std::string out = dir / "run";
  const auto run = RunProgram(
      {Bin("stitch"), "run", "--dataset", sequence.string(), "--out", out, "--failures", "none", "--start-frame", "4"},
      120);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  // One line per frame played, as KITTI's devkit counts them, 12 numbers; those the largest map
  // posed (marked 1) at the ground truth of their frame number, the others holding a neighbour's.
  std::ifstream lines(out + "/trajectory_kitti.txt"), frames(out + "/trajectory_kitti_frames.txt");
  std::string line;
  int lines_read = 0, count = 0, frame = -1, own = -1;
  double worst = 0;
  while (std::getline(lines, line)) {
    ASSERT_TRUE(frames >> frame >> own) << "a frame number and a mark for every line";
    EXPECT_EQ(frame, 4 + lines_read++);
    std::istringstream fields(line);
    double m[12];
    for (double& v : m) ASSERT_TRUE(fields >> v) << line;
    if (!own) continue;
    worst =
        std::max(worst, (Eigen::Vector3d(m[3], m[7], m[11]) - truth.poses()[frame].world_from_cam.translation).norm());
    ++count;
  }
  EXPECT_EQ(lines_read, 36) << "every frame played, from --start-frame 4";
  EXPECT_GE(count, 30) << run.output;
  EXPECT_LT(worst, 1.0) << "metres from the ground truth, on a 40-frame flight over a 69 m strip";
  EXPECT_EQ(count, ReadJson(out + "/report.json")["frames_localized"].get<int>());
  // trajectories/: the largest map's file and an index naming it.
  std::stringstream index;
  index << std::ifstream(out + "/trajectories/index.tsv").rdbuf();
  EXPECT_NE(index.str().find("yes"), std::string::npos) << index.str();
  const std::string first = index.str().substr(index.str().find('\n') + 1);
  EXPECT_EQ(Trajectory::ReadTum(out + "/trajectories/" + first.substr(0, first.find('\t'))).size(),
            static_cast<size_t>(count));
}

// A survey densified elsewhere: the run's map as a COLMAP sparse model on the flight's image
// files, which reads back with a reprojection error under 2 px and which COLMAP accepts; and as a
// COLMAP project database from which COLMAP's mapper rebuilds the model.
TEST(StitchExport, AColmapModelOfARunReadsBackOnItsImagesAndColmapAcceptsIt) {
  testing::TempDir dir;
  const std::string images = dir / "flight";
  const auto render = RenderShortFlight(images, 60);
  ASSERT_EQ(render.exit_code, 0) << render.output;
  const std::string out = dir / "run";
  const auto run = RunProgram({Bin("stitch"), "run", "--dataset", images, "--out", out, "--start-frame", "2"}, 120);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const std::string model_dir = dir / "model";
  const auto exported = RunProgram({Bin("stitch"), "export", "colmap", out, "--out", model_dir}, 60);
  ASSERT_EQ(exported.exit_code, 0) << exported.output;
  const ColmapModel model = ReadColmapModel(model_dir);
  EXPECT_GT(model.images.size(), 10u);
  EXPECT_GT(model.points.size(), 500u);
  EXPECT_LT(ReprojectionRms(model), 2.0);
  ASSERT_EQ(model.cameras.size(), 1u);
  EXPECT_EQ(model.cameras.begin()->second.width(), 640);
  for (const ColmapImage& image : model.images) {
    EXPECT_TRUE(fs::exists(fs::path(images) / image.name)) << image.name;
  }
  // The first keyframe is the first frame played: the third image file.
  EXPECT_EQ(model.images.front().name, RenderedImagesInTimeOrder(images).at(2).filename().string());
  // The points are coloured from the images (the rendered world is not one grey).
  std::set<int> reds;
  for (const ColmapPoint& point : model.points) reds.insert(point.rgb[0]);
  EXPECT_GT(reds.size(), 10u);
  // The run's map.ply is in the images' colours too (the merger, without images, gave it one per
  // submap): each point of the model has its colour there.
  std::map<std::tuple<float, float, float>, std::array<uint8_t, 3>> cloud_colour;
  for (const ColouredPoint& p : ReadPly(out + "/map.ply")) {
    cloud_colour[{p.position.x(), p.position.y(), p.position.z()}] = {p.red, p.green, p.blue};
  }
  size_t same = 0;
  for (const ColmapPoint& point : model.points) {
    const Eigen::Vector3f f = point.position.cast<float>();
    const auto it = cloud_colour.find({f.x(), f.y(), f.z()});
    same += it != cloud_colour.end() && it->second == point.rgb;
  }
  EXPECT_GE(same, 0.95 * model.points.size()) << "of " << model.points.size() << " points";
  // Refused: a second export into the same folder; a run without a model.
  EXPECT_NE(RunProgram({Bin("stitch"), "export", "colmap", out, "--out", model_dir}, 30).exit_code, 0);
  EXPECT_NE(RunProgram({Bin("stitch"), "export", "colmap", dir / "flight", "--out", dir / "m2"}, 30).exit_code, 0);
  if (!testing::OnPath("colmap"))
    GTEST_SKIP() << "COLMAP is not installed (Debian package colmap): model_analyzer not run";
  const auto analyzer =
      RunProgram({"/usr/bin/env", "QT_QPA_PLATFORM=offscreen", "colmap", "model_analyzer", "--path", model_dir}, 120);
  EXPECT_EQ(analyzer.exit_code, 0) << analyzer.output;
  EXPECT_NE(analyzer.output.find("Registered images: " + std::to_string(model.images.size())), std::string::npos)
      << analyzer.output;
  // COLMAP goes on from the database: its own mapper, on the map's matches alone, registers the
  // keyframes again.
  const std::string sparse = dir / "sparse";
  fs::create_directories(sparse);
  const auto mapper = RunProgram(
      {"/usr/bin/env", "QT_QPA_PLATFORM=offscreen", "colmap", "mapper", "--database_path", model_dir + "/database.db",
       "--image_path", images, "--output_path", sparse, "--Mapper.num_threads", "2"},
      300);
  ASSERT_EQ(mapper.exit_code, 0) << mapper.output;
  const auto mapped = RunProgram(
      {"/usr/bin/env", "QT_QPA_PLATFORM=offscreen", "colmap", "model_analyzer", "--path", sparse + "/0"}, 120);
  ASSERT_EQ(mapped.exit_code, 0) << mapped.output;
  const size_t at = mapped.output.find("Registered images: ");
  ASSERT_NE(at, std::string::npos) << mapped.output;
  EXPECT_GE(std::stoi(mapped.output.substr(at + 19)), static_cast<int>(0.9 * model.images.size())) << mapped.output;
}

// The aircraft's camera as it records: the short flight rendered at 1920x1080 and 30 fps into an
// H.264 MP4 by GStreamer's encoder (stitch render --out flight.mp4), then played as a file
// (--dataset) and as a live camera (--live 'filesrc ... ! appsink', at the clip's rate, whatever
// the tracker does). Both are reduced to the working size, and both keep the clip's times, so
// the flight's ground truth applies to either.
TEST(StitchRun, TracksA1080pH264ClipAsAFileAndAsALivePipeline) {
  testing::TempDir dir;
  const std::string video = dir / "flight.mp4";
  const auto render = RunProgram({Bin("stitch"), "render", "--config", kShortFlight, "--set", "synthetic.width=1920",
                                  "--set", "synthetic.height=1080", "--set", "synthetic.focal_px=1350", "--set",
                                  "synthetic.flight.fps=30", "--failures", "none", "--out", video},
                                 120);
  if (render.exit_code != 0 && render.output.find("x264enc") != std::string::npos) {
    GTEST_SKIP() << "GStreamer cannot encode H.264 here (install gstreamer1.0-plugins-ugly): " << render.output;
  }
  ASSERT_EQ(render.exit_code, 0) << render.output;
  const std::string truth = dir / "flight.groundtruth.txt";
  ASSERT_EQ(Trajectory::ReadTum(truth).size(), 60u);
  // Whether each pose of `trajectory` is at a frame's time in the clip (a whole number of 30ths
  // of a second, to within a millisecond).
  const auto at_frame_times = [](const Trajectory& trajectory) {
    for (const auto& pose : trajectory.poses()) {
      const double frames = pose.t_ns * 30e-9;
      if (std::abs(frames - std::round(frames)) > 0.03 || frames > 66) return false;  // a late stamp: a few frames on
    }
    return !trajectory.empty();
  };

  const std::string file_run = dir / "file";
  const auto played = RunProgram({Bin("stitch"), "run", "--dataset", video, "--out", file_run}, 120);
  ASSERT_EQ(played.exit_code, 0) << played.output;
  const auto report = ReadJson(file_run + "/report.json");
  EXPECT_EQ(report["frames_total"], 60);
  EXPECT_EQ(report["has_ground_truth"], true);
  EXPECT_NE(played.output.find("reduced to"), std::string::npos) << played.output;
  EXPECT_GE(report["frames_localized"].get<int>(), 50) << played.output;
  ASSERT_FALSE(report["ate_rmse_m"].is_null());
  EXPECT_LT(report["ate_rmse_m"].get<double>(), 0.3);
  EXPECT_TRUE(at_frame_times(Trajectory::ReadTum(file_run + "/trajectory.tum")));
  // The map in the clip's colours, decoded again at its full size for the keyframes' frames (one
  // colour per submap otherwise).
  std::set<std::array<uint8_t, 3>> colours;
  for (const ColouredPoint& p : ReadPly(file_run + "/map.ply")) colours.insert({p.red, p.green, p.blue});
  EXPECT_GT(colours.size(), 20u) << played.output;
  EXPECT_EQ(played.output.find("colours could not be taken"), std::string::npos) << played.output;

  const std::string pipeline = "filesrc location=" + video + " ! decodebin ! videoconvert ! appsink";
  {
    cv::VideoCapture probe(pipeline, cv::CAP_GSTREAMER);
    cv::Mat frame;
    if (!probe.isOpened() || !probe.read(frame)) {
      GTEST_SKIP() << "GStreamer cannot decode H.264 here (install gstreamer1.0-libav)";
    }
  }
  const std::string live_run = dir / "live";
  const auto live =
      RunProgram({Bin("stitch"), "run", "--live", pipeline, "--calib", dir / "flight.yaml", "--out", live_run}, 120);
  ASSERT_EQ(live.exit_code, 0) << live.output;
  EXPECT_NE(live.output.find("live pacing"), std::string::npos) << live.output;
  EXPECT_EQ(ReadJson(live_run + "/report.json")["run"]["pacing"], "live");
  // The tracker heard of nearly every frame (one captured while the services started may be
  // replaced by a newer one), in order, and posed most of them.
  const auto records = ReadFrameRecords(live_run + "/frames.tsv");
  EXPECT_GE(records.size(), 50u);
  for (size_t i = 1; i < records.size(); ++i) EXPECT_GT(records[i].frame_index, records[i - 1].frame_index);
  // A camera does not wait: on a sanitizer's build, 5-10x slower, most frames are dropped (19-29
  // of 60 localized under AddressSanitizer on a loaded machine; 50 or more in a release build).
  // What counts here is that they keep the clip's times.
  const Trajectory live_trajectory = Trajectory::ReadTum(live_run + "/trajectory.tum");
  EXPECT_GE(live_trajectory.size(), 10u) << live.output;
  EXPECT_TRUE(at_frame_times(live_trajectory));
  // On the clip's clock the flight's ground truth applies, as to the file.
  const auto evaluated = RunProgram(
      {Bin("stitch"), "eval", "--est", live_run + "/trajectory.tum", "--gt", truth, "--out", dir / "live-eval"}, 60);
  ASSERT_EQ(evaluated.exit_code, 0) << evaluated.output;
  const auto live_report = ReadJson(dir / "live-eval/report.json");
  ASSERT_FALSE(live_report["ate_rmse_m"].is_null()) << evaluated.output;
  // Every pose within the ground truth's span is at a time the ground truth has (the evaluator
  // also takes a pose just past either end, within its association tolerance).
  const Trajectory truth_trajectory = Trajectory::ReadTum(truth);
  const auto within_truth =
      std::count_if(live_trajectory.poses().begin(), live_trajectory.poses().end(), [&](const auto& pose) {
        return pose.t_ns >= truth_trajectory.poses().front().t_ns && pose.t_ns <= truth_trajectory.poses().back().t_ns;
      });
  EXPECT_GT(within_truth, 0);
  EXPECT_GE(live_report["frames_with_ground_truth"].get<long>(), within_truth) << evaluated.output;
  EXPECT_LE(live_report["frames_with_ground_truth"].get<long>(), static_cast<long>(live_trajectory.size()));
  // The error is a measure only where the tracker kept up: with most frames dropped (a sanitizer's
  // build on a loaded machine) the map starts from frames far apart, and CI saw 2.7 m from 20-odd
  // poses. A clock off by a frame or more shows here in a release build (about 0.12 m on time).
  if (live_trajectory.size() >= 50) {
    EXPECT_LT(live_report["ate_rmse_m"].get<double>(), 1.0) << live.output;
  }
}

// The processes whose parent is `parent` (from /proc).
std::vector<pid_t> ChildrenOf(pid_t parent) {
  std::vector<pid_t> children;
  for (const auto& entry : fs::directory_iterator("/proc")) {
    const std::string name = entry.path().filename().string();
    if (name.find_first_not_of("0123456789") != std::string::npos) continue;
    std::ifstream stat(entry.path() / "stat");
    std::string line;
    if (!std::getline(stat, line) || line.rfind(')') == std::string::npos) continue;
    std::istringstream fields(line.substr(line.rfind(')') + 2));
    char state = 0;
    pid_t ppid = 0;
    if (fields >> state >> ppid && ppid == parent) children.push_back(std::stoi(name));
  }
  return children;
}

// Running: /proc has it and it is not a zombie waiting to be reaped.
bool Running(pid_t pid) {
  std::ifstream stat("/proc/" + std::to_string(pid) + "/stat");
  std::string line;
  if (!std::getline(stat, line) || line.rfind(')') == std::string::npos) return false;
  return line[line.rfind(')') + 2] != 'Z';
}

// The security issue's row: SIGKILL of the `stitch run` launcher left tracker, mapper and merger
// running as orphans.
// The disk fills up during a run (a file size limit of 24 kB stands in for it: the plot, the
// point clouds and the service logs outgrow it): the run says which file it could not write
// and fails, and leaves no file cut short: each output is whole or absent.
// A straight flight parted by two gusts over new ground: no view joins its three submaps, the
// aircraft's GNSS fixes do (docs/geo.md), in one map, each junction marked.
TEST(StitchRun, AStraightFlightOverNewGroundEndsInOneMapJoinedByGnss) {
  testing::TempDir dir;
  const std::string out = dir / "run";
  const auto run = RunProgram(
      {Bin("stitch"), "run", "--set", "synthetic.flight.num_strips=1", "--set", "synthetic.flight.strip_length_m=504",
       "--set", "synthetic.flight.num_frames=360", "--failures", "110:40,230:40", "--out", out},
      300);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const auto report = ReadJson(out + "/report.json");
  EXPECT_EQ(report["submaps"], 3) << run.output;
  EXPECT_EQ(report["submaps_merged"], 3) << run.output;
  EXPECT_EQ(report["gnss_junctions"], 2) << run.output;
  EXPECT_GE(report["frames_localized"].get<int>(), 250) << run.output;
  int junctions = 0;
  for (const SubmapEdgeRecord& e : ReadSubmapEdgeRecords(out + "/edges.tsv")) {
    junctions += JoinedByGnss(e);
    EXPECT_EQ(e.connected_frames, 0) << "a view joins them: " << e.status;
  }
  EXPECT_EQ(junctions, 2);
  EXPECT_NE(run.output.find("2 of its junctions placed by GNSS"), std::string::npos) << run.output;
  std::ifstream merge_log(out + "/merge_log.tsv");
  const std::string log((std::istreambuf_iterator<char>(merge_log)), std::istreambuf_iterator<char>());
  EXPECT_NE(log.find("joined where GNSS places their maps"), std::string::npos) << log;
  // The one map on Earth: its keyframes within a couple of metres of the truth, unaligned (2 m fixes).
  const auto geo = ReadJson(out + "/geo/georeference.json");
  ASSERT_EQ(geo["maps"].size(), 1u) << geo.dump();
  EXPECT_EQ(geo["maps"][0]["submaps"], "0:1,0:2,0:3");
  EXPECT_LT(geo["maps"][0]["absolute"]["keyframe_horizontal_rms_m"].get<double>(), 2.0) << geo.dump();
  EXPECT_LT(std::abs(geo["maps"][0]["absolute"]["scale_error"].get<double>()), 0.01) << geo.dump();
  // The map's COLMAP model in the same ENU metres: each camera near the truth's path, not in the
  // map's units, and every feature still where its camera sees its point.
  const ColmapModel enu_model = ReadColmapModel(out + "/geo/colmap_enu");
  EXPECT_EQ(enu_model.images.size(), ReadColmapModel(out + "/colmap").images.size());
  const Trajectory truth = Trajectory::ReadTum(out + "/groundtruth.tum");
  double squared = 0;
  for (const ColmapImage& image : enu_model.images) {
    double nearest = std::numeric_limits<double>::infinity();
    for (const StampedPose& p : truth.poses()) {
      nearest = std::min(nearest, (p.world_from_cam.translation - image.cam_from_world.CentreInWorld()).squaredNorm());
    }
    squared += nearest;
  }
  EXPECT_LT(std::sqrt(squared / enu_model.images.size()), 3.0);
  EXPECT_LT(ReprojectionRms(enu_model), 2.0);
  // The same figures from the files a surveyor gets, with no alignment: the WGS 84 trajectory
  // against the truth in the ENU frame at the origin the run states.
  const auto& origin = geo["origin"];
  char at[96];
  std::snprintf(at, sizeof(at), "%.9f,%.9f,%.3f", origin["latitude_deg"].get<double>(),
                origin["longitude_deg"].get<double>(), origin["height_m"].get<double>());
  const auto eval = RunProgram({Bin("stitch"), "eval", "--absolute", "--est", out + "/geo/trajectory_wgs84.csv", "--gt",
                                out + "/groundtruth.tum", "--origin", at, "--out", dir / "absolute"},
                               60);
  ASSERT_EQ(eval.exit_code, 0) << eval.output;
  const auto absolute = ReadJson(dir / "absolute/absolute.json");
  EXPECT_EQ(absolute["matched"], geo["maps"][0]["absolute"]["frames"]) << absolute.dump();
  EXPECT_NEAR(absolute["horizontal_rms_m"].get<double>(), geo["maps"][0]["absolute"]["horizontal_rms_m"].get<double>(),
              0.002)
      << absolute.dump();
  EXPECT_NEAR(absolute["vertical_rms_m"].get<double>(), geo["maps"][0]["absolute"]["vertical_rms_m"].get<double>(),
              0.002)
      << absolute.dump();
  // Without the origin, a WGS 84 trajectory and one in a local frame are not compared.
  const auto refused = RunProgram({Bin("stitch"), "eval", "--absolute", "--est", out + "/geo/trajectory_wgs84.csv",
                                   "--gt", out + "/groundtruth.tum"},
                                  60);
  EXPECT_EQ(refused.exit_code, 1) << refused.output;
  EXPECT_NE(refused.output.find("--origin"), std::string::npos) << refused.output;
}

TEST(StitchRun, AFullDiskIsReportedWithTheFileAndLeavesNoFileCut) {
  testing::TempDir dir;
  const std::string out = dir / "run";
  testing::CommandResult run;
  {
    const testing::FullDiskAfter full(24 * 1024);  // inherited by stitch run and its services
    run = RunProgram({Bin("stitch"), "run", "--config", kShortFlight, "--out", out, "--failures", "none"}, 180);
  }
  EXPECT_NE(run.exit_code, 0) << run.output;
  EXPECT_NE(run.exit_code, 134) << "crashed: " << run.output;
  EXPECT_NE(run.output.find(": write failed (File too large)"), std::string::npos) << run.output;
  EXPECT_NE(run.output.find(out), std::string::npos) << "names the file: " << run.output;
  for (const auto& entry : fs::recursive_directory_iterator(out)) {
    EXPECT_NE(entry.path().extension(), ".partial") << entry.path();
  }
  if (fs::exists(out + "/trajectory.tum")) {
    EXPECT_NO_THROW(Trajectory::ReadTum(out + "/trajectory.tum"));
  }
  if (fs::exists(out + "/report.json")) {
    EXPECT_NO_THROW(ReadJson(out + "/report.json"));
  }
  if (fs::exists(out + "/map.ply")) {
    EXPECT_NO_THROW(ReadPly(out + "/map.ply"));
  }
}

TEST(StitchRun, ItsServicesEndWhenTheLauncherIsKilled) {
  testing::TempDir dir;
  ChildProcess launcher("run", Bin("stitch"), {"run", "--quiet", "--out", dir / "run"}, dir / "run.log");
  std::vector<pid_t> services;
  for (int i = 0; i < 600 && services.size() < 4; ++i) {  // ingest, tracker, mapper, merger
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    services = ChildrenOf(launcher.pid());
  }
  ASSERT_GE(services.size(), 4u) << launcher.LogTail(10);
  ASSERT_EQ(kill(launcher.pid(), SIGKILL), 0);
  EXPECT_EQ(launcher.Terminate(std::chrono::milliseconds(5000)), 128 + SIGKILL);
  for (pid_t service : services) {
    for (int i = 0; i < 300 && Running(service); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(50));
    EXPECT_FALSE(Running(service)) << "service " << service << " still runs 15 s after the launcher was killed";
    if (Running(service)) kill(service, SIGKILL);
  }
}

// A live camera with its flight controller beside it: stitch-ingest listens for the controller's
// MAVLink telemetry on UDP (ingest.gnss_receiver) and puts its GPS fixes on <agent>/GNSS, stamped
// with the wall clock the live frames carry; garbage and damaged datagrams give none.
TEST(StitchIngest, PublishesAFlightControllersMavlinkFixesBesideALiveCamera) {
  testing::TempDir dir;
  const std::string calibration = dir / "camera.yaml";
  SaveCalibration(Camera(CameraModel::kPinholeRadTan, 320, 240, {300, 300, 160, 120, 0, 0, 0, 0, 0}), calibration);
  const std::string url = "udpm://239.255.76.67:" + std::to_string(bus::UnusedUdpPort()) + "?ttl=0";
  const int mavlink_port = bus::UnusedUdpPort(32000, 1000);
  lcm::LCM listener(url);
  ASSERT_TRUE(listener.good());
  std::vector<std::pair<double, int64_t>> heard;  // latitude, t_ns
  struct Handler {
    std::vector<std::pair<double, int64_t>>* heard;
    void On(const lcm::ReceiveBuffer*, const std::string&, const stitch::gnss_fix_t* fix) {
      heard->emplace_back(fix->latitude_deg, fix->t_ns);
    }
  } handler{&heard};
  listener.subscribe("uav0/GNSS", &Handler::On, &handler);
  std::atomic<bool> done{false};
  std::thread listening([&] {
    while (!done.load()) listener.handleTimeout(50);
  });
  const int64_t started_ns = WallClockNs();
  testing::CommandResult ingest;
  std::thread running([&] {
    ingest = RunProgram(
        {Bin("stitch-ingest"), "--live",
         "videotestsrc is-live=true num-buffers=90 ! video/x-raw,width=320,height=240,framerate=30/1 ! "
         "videoconvert ! appsink",
         "--live-clock", "wall", "--calib", calibration, "--lcm-url", url, "--set", "ingest.wait_for_tracker_s=0",
         "--set", "ingest.gnss_receiver=mavlink:127.0.0.1:" + std::to_string(mavlink_port)},
        60);
  });
  // The controller: a fix every 100 ms, each a little further north, among garbage and damage.
  const int sender = socket(AF_INET, SOCK_DGRAM, 0);
  sockaddr_in to{};
  to.sin_family = AF_INET;
  to.sin_port = htons(static_cast<uint16_t>(mavlink_port));
  inet_pton(AF_INET, "127.0.0.1", &to.sin_addr);
  MavlinkGpsRawInt raw;
  raw.lat_e7 = 473684230;
  raw.lon_e7 = 85390540;
  raw.alt_mm = 460'000;
  raw.fix_type = 3;
  raw.h_acc_mm = 1500;
  raw.v_acc_mm = 3000;
  for (int i = 0; i < 40; ++i) {
    raw.lat_e7 += 10;
    std::vector<uint8_t> frame = EncodeMavlinkFrame(kMavlinkGpsRawInt, MavlinkPayload(raw));
    if (i % 4 == 3) frame[14] ^= 0x10;  // damaged: refused by its CRC
    const std::vector<uint8_t> garbage = {0xFD, 0x30, 0x00, 0x00, 0x01, 0x01, 0x18};
    sendto(sender, garbage.data(), garbage.size(), 0, reinterpret_cast<const sockaddr*>(&to), sizeof(to));
    sendto(sender, frame.data(), frame.size(), 0, reinterpret_cast<const sockaddr*>(&to), sizeof(to));
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  close(sender);
  running.join();
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  done = true;
  listening.join();
  const int64_t ended_ns = WallClockNs();
  ASSERT_EQ(ingest.exit_code, 0) << ingest.output;
  // While the camera ran (3 s) the controller sent about 30 fixes, a quarter of them damaged.
  EXPECT_GE(heard.size(), 12u) << ingest.output;
  EXPECT_LE(heard.size(), 30u) << ingest.output;
  for (size_t i = 0; i < heard.size(); ++i) {
    EXPECT_GT(heard[i].second, started_ns);
    EXPECT_LT(heard[i].second, ended_ns);
    if (i > 0) {
      EXPECT_GT(heard[i].first, heard[i - 1].first) << "in order";
    }
    const int sent = static_cast<int>(std::lround((heard[i].first - 47.368423) * 1e6));  // lat_e7 steps of 10
    EXPECT_NE(sent % 4, 0) << "fix " << sent << " was sent damaged";
  }
  EXPECT_NE(ingest.output.find("GNSS fixes from MAVLink"), std::string::npos) << ingest.output;

  // A recorded sequence keeps its own clock: MAVLink fixes stamped on arrival would not fit it.
  const auto refused = RunProgram({Bin("stitch-ingest"), "--config", testing::ShortFlightConfig(), "--lcm-url",
                                   "memq://", "--set", "ingest.gnss_receiver=gpsd"},
                                  60);
  EXPECT_NE(refused.exit_code, 0);
  EXPECT_NE(refused.output.find("ingest.gnss_receiver needs a live camera"), std::string::npos) << refused.output;
}

// A survey flown as photos: each JPEG carries the aircraft's position in its EXIF GPS tags (as a
// survey camera or a drone writes them), and there is no gnss.csv. The run reads the tags, each at
// its photo's time, and places the map on Earth by them.
TEST(StitchRun, PlacesAFolderOfPhotosOnEarthByTheirExifGpsTags) {
  testing::TempDir dir;
  const std::string rendered = dir / "rendered";
  const auto render =
      RunProgram({Bin("stitch"), "render", "--config", kShortFlight, "--failures", "none", "--out", rendered}, 120);
  ASSERT_EQ(render.exit_code, 0) << render.output;
  const GnssTrack truth_fixes = ReadGnssCsv(rendered + "/gnss.csv");
  ASSERT_GT(truth_fixes.fixes.size(), 10u);
  const std::string photos = dir / "photos";
  std::filesystem::create_directories(photos);
  for (const char* file : {"camera.yaml", "groundtruth.txt"}) {
    std::filesystem::copy_file(std::filesystem::path(rendered) / file, std::filesystem::path(photos) / file);
  }
  // A camera's EXIF altitude is above mean sea level: the synthetic fixes' ellipsoidal heights
  // less the geoid's (about 46 m here), which the run adds back.
  const Geoid geoid = Geoid::Egm96();
  const auto fix_nearest = [&truth_fixes](int64_t t_ns) {
    const GnssFix* nearest = &truth_fixes.fixes.front();
    for (const GnssFix& fix : truth_fixes.fixes) {
      if (std::llabs(fix.t_ns - t_ns) < std::llabs(nearest->t_ns - t_ns)) nearest = &fix;
    }
    return nearest;
  };
  int written = 0;
  for (const auto& [t_ns, png] : FolderImageTimes(rendered)) {
    // The fix nearest the photo's time, as a camera triggered by the autopilot tags it.
    const GnssFix* nearest = fix_nearest(t_ns);
    const std::string jpeg = photos + "/" + std::filesystem::path(png).stem().string() + ".jpg";
    ASSERT_TRUE(cv::imwrite(jpeg, cv::imread(png, cv::IMREAD_UNCHANGED), {cv::IMWRITE_JPEG_QUALITY, 95}));
    GeodeticPoint above_sea_level = nearest->position;
    above_sea_level.height_m -= geoid.HeightAboveEllipsoid(above_sea_level.latitude_deg, above_sea_level.longitude_deg);
    WriteExifGps(jpeg, above_sea_level);
    ++written;
  }
  ASSERT_GE(written, 50);
  const std::string out = dir / "run";
  const auto run = RunProgram({Bin("stitch"), "run", "--dataset", photos, "--failures", "none", "--out", out}, 300);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const auto geo = ReadJson(out + "/geo/georeference.json");
  ASSERT_GE(geo["maps"].size(), 1u) << geo.dump() << run.output;
  EXPECT_NE(geo["gnss_source"].get<std::string>().find("EXIF GPS tags of"), std::string::npos) << geo.dump();
  EXPECT_EQ(geo["maps"][0]["placed"], true) << geo.dump();
  EXPECT_GE(geo["maps"][0]["inliers"].get<int>(), 10) << geo.dump();
  // The synthetic receiver's fixes have 2 m of noise; the photos' tags carry them to the metre.
  EXPECT_LT(geo["maps"][0]["horizontal_rms_m"].get<double>(), 5.0) << geo.dump();
  // On the ellipsoid, as the fixes were flown: each placed camera's height within a few metres of
  // the fix nearest its time (read as mean sea level, they would sit 46 m lower).
  std::ifstream wgs84(out + "/geo/trajectory_wgs84.csv");
  std::vector<double> height_errors;
  for (std::string line; std::getline(wgs84, line);) {
    if (line.empty() || line[0] == '#' || line.rfind("map,", 0) == 0) continue;
    std::vector<std::string> field;
    std::stringstream row(line);
    for (std::string f; std::getline(row, f, ',');) field.push_back(f);
    ASSERT_EQ(field.size(), 6u) << line;
    height_errors.push_back(std::abs(std::stod(field[5]) - fix_nearest(std::stoll(field[2]))->position.height_m));
  }
  ASSERT_GT(height_errors.size(), 10u);
  std::nth_element(height_errors.begin(), height_errors.begin() + height_errors.size() / 2, height_errors.end());
  EXPECT_LT(height_errors[height_errors.size() / 2], 8.0);
  // The photos' orthomosaic, from the JPEG files, in UTM.
  const auto mosaic = RunProgram({Bin("stitch"), "mosaic", out}, 120);
  ASSERT_EQ(mosaic.exit_code, 0) << mosaic.output;
  EXPECT_EQ(ReadGeoTiffInfo(out + "/ortho.tif").epsg, 32632);
  EXPECT_FALSE(ReadJson(out + "/ortho.json").contains("truth"));
}

}  // namespace
}  // namespace stitch
