// What a run's outputs say about it, from its records alone (no services run).

#include "tools/stitch/launch/run_outputs.h"

#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>

#include <gtest/gtest.h>

#include "stitch/geo/las.h"

#include "stitch/geo/gnss_fix.h"
#include "stitch/io/ply.h"
#include "stitch/records/frame_record.h"
#include "stitch/records/source_record.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/tracking/tracking_result.h"

namespace stitch {
namespace {

// A run folder whose frames.tsv holds `records`.
void WriteFrames(const testing::TempDir& dir, const std::vector<FrameRecord>& records) {
  std::ofstream out(dir / "frames.tsv");
  out << FrameRecordHeader();
  for (const FrameRecord& r : records) out << FormatFrameRecord(r);
}

FrameRecord Frame(int index, const std::string& state, TrackingReason reason) {
  FrameRecord r;
  r.frame_index = index;
  r.t_ns = index * 50'000'000LL;
  r.state = state;
  r.reason = static_cast<int>(reason);
  return r;
}

bool SomeNoteSays(const RunInfo& info, const std::string& text) {
  for (const std::string& note : info.notes) {
    if (note.find(text) != std::string::npos) return true;
  }
  return false;
}

// A camera that never moved enough to begin a map (EuRoC's micro sequence on the ground): the
// summary says why no frame was localized instead of only "0 of 95".
TEST(RunOutputs, SaysWhyNoFrameWasLocalized) {
  testing::TempDir dir;
  std::vector<FrameRecord> records;
  for (int i = 0; i < 5; ++i) records.push_back(Frame(i, "INITIALIZING", TrackingReason::kInitFailed));
  records.push_back(Frame(5, "NOT_TRACKED", TrackingReason::kTooFewFeatures));
  WriteFrames(dir, records);
  RunInfo info;
  info.frames_total = 6;
  FinishRunOutputs(dir.path().string(), &info);
  EXPECT_TRUE(SomeNoteSays(info,
                           "no frame was localized: 5 initializing (initialization failed), 1 not tracked "
                           "(too few features)"));
  EXPECT_TRUE(SomeNoteSays(info, "min_parallax_deg"));
}

TEST(RunOutputs, SaysNothingOfTheKindWhereAFrameWasLocalized) {
  testing::TempDir dir;
  WriteFrames(dir, {Frame(0, "INITIALIZING", TrackingReason::kInitFailed), Frame(1, "OK", TrackingReason::kNone)});
  RunInfo info;
  info.frames_total = 2;
  FinishRunOutputs(dir.path().string(), &info);
  EXPECT_FALSE(SomeNoteSays(info, "no frame was localized"));
}

// A source that could not keep its camera's pace (ingest.json): its late frames are in the
// evaluation, report.json and the summary; a damaged record is a note.
TEST(RunOutputs, CountsTheFramesTheSourceSentLate) {
  testing::TempDir dir;
  WriteFrames(dir, {Frame(0, "OK", TrackingReason::kNone), Frame(1, "OK", TrackingReason::kNone)});
  SourceRecord source;
  source.frames_published = 2;
  source.frames_late = 1;
  WriteSourceRecord(dir / "ingest.json", source);
  RunInfo info;
  info.frames_total = 2;
  const Evaluation evaluation = FinishRunOutputs(dir.path().string(), &info);
  EXPECT_EQ(evaluation.frames_late_at_source, 1);
  EXPECT_NE(Summarize(evaluation).find("1 frames left the source more than a frame late"), std::string::npos)
      << Summarize(evaluation);
  std::ifstream in(dir / "report.json");
  EXPECT_EQ(nlohmann::json::parse(in)["frames_late_at_source"], 1);

  std::ofstream(dir / "ingest.json", std::ios::trunc) << "{";
  RunInfo again;
  again.frames_total = 2;
  EXPECT_EQ(FinishRunOutputs(dir.path().string(), &again).frames_late_at_source, 0);
  EXPECT_TRUE(SomeNoteSays(again, "ingest.json: not a source record"));
}

// A run folder with the aircraft's GNSS fixes: the largest map placed on Earth (geo/), the
// figures in the summary and report.json; a damaged gnss.csv is a note, not a failed run.
TEST(RunOutputs, PlacesTheRunOnEarthWhereItHasFixes) {
  testing::TempDir dir;
  std::vector<FrameRecord> records;
  GnssTrack gnss;
  gnss.source = "test";
  gnss.ground_truth_enu_origin = GeodeticPoint{48.0, 11.0, 600.0};
  const LocalTangentPlane plane(*gnss.ground_truth_enu_origin);
  Trajectory truth;
  for (int i = 0; i < 400; ++i) {
    FrameRecord r = Frame(i, "OK", TrackingReason::kNone);
    r.submap_id = 1;
    const int strip = i / 100;
    const Eigen::Vector3d centre(strip % 2 ? 99 - i % 100 : i % 100, 30.0 * strip, 70.0);
    truth.Add({r.t_ns, Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX())), centre)});
    // The map's own frame: a tenth of a metre, turned.
    r.world_from_cam = TransformPose(
        Sim3d(0.1, Eigen::Quaterniond(Eigen::AngleAxisd(0.5, Eigen::Vector3d::UnitZ())), Eigen::Vector3d(1, 2, 3)),
        truth.poses().back().world_from_cam);
    records.push_back(r);
    if (i % 4 == 0) {
      GnssFix fix;
      fix.t_ns = r.t_ns;
      fix.position = plane.ToGeodetic(centre);
      fix.horizontal_accuracy_m = 1;
      fix.vertical_accuracy_m = 1;
      gnss.fixes.push_back(fix);
    }
  }
  WriteFrames(dir, records);
  WriteGnssCsv(dir / "gnss.csv", gnss);
  truth.WriteTum(dir / "groundtruth.tum");
  // The map's points: one where its first camera is (the truth's (0, 0, 70) m).
  ColouredPoint camera_point;
  camera_point.position = records.front().world_from_cam.translation.cast<float>();
  WritePly(dir / "map.ply", {camera_point});
  RunInfo info;
  info.frames_total = 400;
  FinishRunOutputs(dir.path().string(), &info);
  ASSERT_EQ(info.geo_figures.size(), 2u);
  EXPECT_NE(info.geo_figures[1].find("placed by 100 of 100 fixes"), std::string::npos) << info.geo_figures[1];
  for (const char* file : {"trajectory_wgs84.csv", "trajectory.geojson", "trajectory.kml", "georeference.json"}) {
    EXPECT_TRUE(std::filesystem::exists(dir.path() / "geo" / file)) << file;
  }
  // map.ply in metres east, north and up of the origin.
  const std::vector<ColouredPoint> enu = ReadPly((dir.path() / "geo" / "map_enu.ply").string());
  ASSERT_EQ(enu.size(), 1u);
  EXPECT_LT((enu[0].position - Eigen::Vector3f(0, 0, 70)).norm(), 0.05f) << enu[0].position.transpose();
  // ...and in WGS 84 / UTM as LAS.
  const LasCloud las = ReadLas((dir.path() / "geo" / "map_utm.las").string());
  ASSERT_EQ(las.points.size(), 1u);
  EXPECT_GT(las.epsg, 32600);
  std::ifstream in(dir / "report.json");
  const nlohmann::json report = nlohmann::json::parse(in);
  EXPECT_LT(report["georeference"]["maps"][0]["absolute"]["horizontal_rms_m"].get<double>(), 0.01);

  // A damaged map.ply: the trajectory is still placed, and a note says why the map is not.
  std::ofstream(dir / "map.ply", std::ios::trunc) << "ply\nformat ascii 1.0\n";
  RunInfo damaged;
  damaged.frames_total = 400;
  FinishRunOutputs(dir.path().string(), &damaged);
  EXPECT_EQ(damaged.geo_figures.size(), 2u);
  EXPECT_TRUE(SomeNoteSays(damaged, "geo/map_enu.ply, map_utm.las not written: "));
  EXPECT_FALSE(std::filesystem::exists(dir.path() / "geo" / "map_enu.ply"));
  EXPECT_FALSE(std::filesystem::exists(dir.path() / "geo" / "map_utm.las"));

  std::ofstream(dir / "gnss.csv", std::ios::app) << "1,2,3\n";
  RunInfo again;
  again.frames_total = 400;
  FinishRunOutputs(dir.path().string(), &again);
  EXPECT_TRUE(again.geo_figures.empty());
  EXPECT_FALSE(std::filesystem::exists(dir.path() / "geo" / "map_enu.ply"));  // not placed this time
  EXPECT_FALSE(std::filesystem::exists(dir.path() / "geo" / "map_utm.las"));
  EXPECT_TRUE(SomeNoteSays(again, "not placed on Earth: " + (dir / "gnss.csv") + ":"));
}

}  // namespace
}  // namespace stitch
