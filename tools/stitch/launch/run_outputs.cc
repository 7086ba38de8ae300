#include "tools/stitch/launch/run_outputs.h"

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>

#include "stitch/config/stitch_config.h"
#include "stitch/eval/georeference.h"
#include "stitch/io/colmap_model.h"
#include "stitch/io/image_sequence.h"
#include "stitch/io/output_frames.h"
#include "stitch/io/ply.h"
#include "stitch/io/trajectory.h"
#include "stitch/merging/frame_trajectory.h"
#include "stitch/records/frame_record.h"
#include "stitch/records/keyframe_record.h"
#include "stitch/records/merger_records.h"
#include "stitch/records/source_record.h"
#include "stitch/tracking/tracking_result.h"
#include "stitch/util/error.h"
#include "stitch/util/ids.h"
#include "stitch/util/text_file.h"
#include "tools/stitch/launch/map_colours.h"

namespace fs = std::filesystem;

namespace stitch {

namespace {

// trajectories/: every map's frames in TUM format, each in its own frame: a merged map of several
// submaps as map-K.tum (K = 0 the largest, then by frames), a submap on its own as
// submap-A-N.tum; index.tsv says which submaps each holds.
void WriteEveryTrajectory(const std::string& folder, const std::vector<PoseRecord>& poses, int largest_component) {
  fs::remove_all(folder);
  fs::create_directories(folder);
  std::map<int, Trajectory> by_component;
  for (const auto& p : poses) by_component[p.component].Add({p.t_ns, p.world_from_cam});
  std::ostringstream index;
  index << "file\tframes\tsubmaps\tlargest\n";
  for (const RunMap& map : MapsOfRun(poses, largest_component)) {
    by_component[map.component].WriteTum((fs::path(folder) / (map.name + ".tum")).string(), output_frames::kOwnMap);
    index << map.name << ".tum\t" << map.frames << "\t" << map.SubmapNames() << "\t" << (map.largest ? "yes" : "no")
          << "\n";
  }
  WriteFileAtomically((fs::path(folder) / "index.tsv").string(), index.str());
}

// For a KITTI sequence: the largest map in KITTI's format (the 3x4 world_from_cam, row by row),
// in the ground truth's frame and scale when it can be aligned, one line for every frame played,
// as KITTI's devkit counts them: a frame the largest map does not hold takes the pose of the
// nearest earlier one it holds (the first it holds, before that). trajectory_kitti_frames.txt
// gives each line's frame number in the sequence (--start-frame counted) and whether the map
// posed it (1) or the line holds a neighbour's pose (0).
void WriteKittiTrajectory(const std::string& dir, const std::vector<PoseRecord>& poses, const Evaluation& evaluation,
                          int start_frame, int frames_played) {
  const Sim3d align = evaluation.errors ? evaluation.errors->ground_truth_from_estimate : Sim3d();
  std::map<int, Sim3d> posed;  // by frame played
  for (const auto& p : poses) {
    if (p.component != evaluation.largest_component) continue;
    posed[p.frame_index] = align * Sim3d(1.0, p.world_from_cam.rotation, p.world_from_cam.translation);
  }
  std::ostringstream lines, frames;
  lines.precision(9);
  for (int frame = 0; frame < frames_played; ++frame) {
    auto it = posed.upper_bound(frame);                                     // the first posed after `frame`
    const bool own = it != posed.begin() && std::prev(it)->first == frame;  // posed by the map itself
    if (it != posed.begin()) --it;  // the nearest at or before it, where there is one
    const Sim3d pose = it == posed.end() ? Sim3d() : it->second;
    const Eigen::Matrix3d r = pose.rotation.toRotationMatrix();
    for (int row = 0; row < 3; ++row) {
      lines << r(row, 0) << " " << r(row, 1) << " " << r(row, 2) << " " << pose.translation[row]
            << (row == 2 ? "\n" : " ");
    }
    frames << start_frame + frame << " " << (own ? 1 : 0) << "\n";
  }
  WriteFileAtomically((fs::path(dir) / "trajectory_kitti.txt").string(), lines.str());
  WriteFileAtomically((fs::path(dir) / "trajectory_kitti_frames.txt").string(), frames.str());
}

// Where no frame was localized: why, from the frames' states and reasons ("95 initializing
// (initialization failed)"), and what a map needs to begin. Empty when some frame was localized.
std::string WhyNothingWasLocalized(const std::vector<FrameRecord>& records) {
  std::map<std::string, int> counts;  // "initializing (initialization failed)" -> frames
  for (const FrameRecord& r : records) {
    if (r.state == "OK") return "";
    std::string state = r.state;
    for (char& c : state) c = static_cast<char>(c == '_' ? ' ' : std::tolower(static_cast<unsigned char>(c)));
    const bool known = r.reason > 0 && r.reason <= static_cast<int>(TrackingReason::kNotRelocalized);
    counts[state +
           (known ? std::string(" (") + TrackingReasonName(static_cast<TrackingReason>(r.reason)) + ")" : "")]++;
  }
  std::string text;
  for (const auto& [what, frames] : counts) text += (text.empty() ? "" : ", ") + std::to_string(frames) + " " + what;
  return "no frame was localized: " + text +
         ". A map begins from two views of the same features with enough parallax between them "
         "(tracker.tracking.initialization.min_parallax_deg): a camera that does not move sideways, or sees "
         "too little texture, never starts one; logs/tracker.log says why each frame waited";
}

}  // namespace

Evaluation FinishRunOutputs(const std::string& run_dir, RunInfo* info) {
  const fs::path dir(run_dir);
  EvaluationInput input;
  input.frames_total = info->frames_total;
  input.frames_unusable = info->frames_unusable;

  std::vector<FrameRecord> records;
  if (fs::exists(dir / "frames.tsv")) records = ReadFrameRecords((dir / "frames.tsv").string());
  if (info->frames_total < 0) {
    // A live source: as many frames as the tracker heard of (dropped ones are reported too).
    int highest = -1;
    for (const auto& r : records) highest = std::max(highest, r.frame_index);
    info->frames_total = highest + 1;
    input.frames_total = info->frames_total;
  }
  // Final keyframe poses from the mapper (culled keyframes placed through their parents).
  std::map<int64_t, KeyframeInSubmap> keyframes;
  int keyframes_retained = 0;
  if (fs::exists(dir / "keyframes.tsv")) {
    for (const KeyframeRecord& k : ReadKeyframeRecords((dir / "keyframes.tsv").string())) {
      keyframes[k.keyframe_id] = {k.world_from_cam.Inverse(), k.frame_index};
      keyframes_retained += !k.culled;
    }
  }
  std::set<int64_t> submaps;
  int keyframes_made = 0;
  constexpr int kReasonUndecodable = static_cast<int>(TrackingReason::kUndecodableFrame);
  constexpr int kReasonDropped = static_cast<int>(TrackingReason::kDropped);
  for (const auto& r : records) {
    input.frames_unreadable += r.reason == kReasonUndecodable;
    input.frames_dropped += r.reason == kReasonDropped;
    if (r.tracking_ms > 0) input.tracking_ms.push_back(r.tracking_ms);
    if (r.is_keyframe) ++keyframes_made;
    if (r.state == "OK") submaps.insert(r.submap_id);
  }
  input.keyframes = fs::exists(dir / "keyframes.tsv") ? keyframes_retained : keyframes_made;
  if (fs::exists(dir / "ingest.json")) {
    try {
      input.frames_late_at_source = ReadSourceRecord((dir / "ingest.json").string()).frames_late;
    } catch (const Error& e) {
      info->notes.push_back(e.what());
    }
  }
  input.submaps = static_cast<int>(submaps.size());

  // The tracker's poses, each re-composed with the mapper's final pose of the keyframe it was
  // tracked against and placed by the merger (submaps.tsv, keyframes_merged.tsv); a submap the
  // merger did not place is a map of its own.
  {
    std::vector<TrackedFramePose> tracked;
    std::map<int64_t, int> own_component;  // for submaps without a placement, by first frame
    for (const auto& r : records) {
      if (r.state != "OK") continue;
      own_component.try_emplace(r.submap_id, static_cast<int>(own_component.size()));
      tracked.push_back({r.frame_index, r.t_ns, r.submap_id, r.is_keyframe, r.world_from_cam, r.reference_keyframe,
                         r.cam_from_reference});
    }
    std::map<int64_t, SubmapInMap> placement;
    std::map<int64_t, Sim3d> refined;
    const bool merger_ran = fs::exists(dir / "submaps.tsv");
    if (merger_ran) {
      for (const SubmapRecord& r : ReadSubmapRecords((dir / "submaps.tsv").string())) {
        placement[r.submap.value] = {r.component, r.world_from_submap};
      }
      if (fs::exists(dir / "keyframes_merged.tsv")) {
        for (const MergedKeyframeRecord& r : ReadMergedKeyframeRecords((dir / "keyframes_merged.tsv").string())) {
          refined[r.keyframe.value] = r.world_from_cam;
        }
      }
    }
    input.poses = PlaceTrackedFrames(tracked, keyframes, placement, refined);
    for (PoseRecord& p : input.poses) {
      // The merger never heard of it (or there was no merger): a map of its own.
      if (p.component < 0) p.component = (merger_ran ? 1000 : 0) + own_component[p.submap_id];
    }
  }
  WritePoseRecords((dir / "poses.tsv").string(), input.poses);
  if (fs::exists(dir / "groundtruth.tum")) input.ground_truth = Trajectory::ReadTum((dir / "groundtruth.tum").string());

  std::vector<SubmapEdgeRecord> edges;  // the merger's verdict on every pair of submaps it connected
  if (fs::exists(dir / "edges.tsv")) edges = ReadSubmapEdgeRecords((dir / "edges.tsv").string());
  if (std::any_of(edges.begin(), edges.end(), [](const SubmapEdgeRecord& e) { return JoinedByGnss(e); })) {
    input.view_part = ViewJoinedParts(edges);  // merges by views are judged within their part
  }
  Evaluation evaluation = Evaluate(input);
  for (const SubmapEdgeRecord& e : edges) evaluation.gnss_junctions += JoinedByGnss(e);

  // trajectory.tum: the largest merged map, in its own frame.
  Trajectory trajectory;
  for (const auto& p : input.poses) {
    if (p.component == evaluation.largest_component) trajectory.Add({p.t_ns, p.world_from_cam});
  }
  trajectory.WriteTum((dir / "trajectory.tum").string(), output_frames::kLargestMap);
  WriteEveryTrajectory((dir / "trajectories").string(), input.poses, evaluation.largest_component);
  if (info->source.rfind("KITTI ", 0) == 0) {
    WriteKittiTrajectory(dir.string(), input.poses, evaluation, info->start_frame, info->frames_total);
  }
  if (!fs::exists(dir / "map.ply")) {
    WritePly((dir / "map.ply").string(), {}, output_frames::kLargestMap);
    info->notes.push_back("map.ply is empty: no merger wrote a map in this run");
  } else if (!info->dataset.empty() && fs::exists(dir / "colmap" / "images.txt")) {
    // The map in the flight's colours: the merger, on the ground, has no images; the run's
    // dataset does.
    const fs::path scratch = dir / ".dataset-camera.yaml";
    try {
      ColmapModel model = ReadColmapModel((dir / "colmap").string());
      model = DetectDatasetKind(info->dataset) == "video"
                  ? ColourFromVideo(std::move(model), info->dataset, info->start_frame)
                  : ModelOnImages(std::move(model), info->dataset, info->start_frame, scratch.string());
      fs::remove(scratch);
      ColourCloudFromModel((dir / "map.ply").string(), model, output_frames::kLargestMap);
      if (fs::exists(dir / "map_raw.ply")) {
        ColourCloudFromModel((dir / "map_raw.ply").string(), model, output_frames::kLargestMap);
      }
    } catch (const Error& e) {
      std::error_code ignored;
      fs::remove(scratch, ignored);
      info->notes.push_back(std::string("map.ply's colours could not be taken from the images: ") + e.what());
    }
  }
  if (records.empty()) {
    info->notes.push_back("the tracker reported no frame (see logs/tracker.log)");
  } else if (const std::string why = WhyNothingWasLocalized(records); !why.empty()) {
    info->notes.push_back(why);
  }
  if (static_cast<int>(records.size()) < info->frames_total && !info->interrupted) {
    info->notes.push_back(std::to_string(info->frames_total - static_cast<int>(records.size())) +
                          " frames never reached the tracker");
  }

  // The merger's verdict on every pair of submaps with connected frames; the refused ones said.
  nlohmann::json merges = nullptr;
  if (fs::exists(dir / "edges.tsv")) {
    merges = nlohmann::json::array();
    for (const SubmapEdgeRecord& e : edges) {
      merges.push_back({{"submap_a", SubmapName(e.a)},
                        {"submap_b", SubmapName(e.b)},
                        {"strength", e.strength},
                        {"connected_frames", e.connected_frames},
                        {"map_points", e.map_points},
                        {"outvoted_frames", e.disagreeing_frames},
                        {"median_angle_deg", e.median_angle_deg},
                        {"agreement", e.agreement},
                        {"status", e.status}});
      if (e.status.rfind("refused", 0) == 0) {
        char strength[32];
        std::snprintf(strength, sizeof(strength), "%.1f", e.strength);
        info->notes.push_back("submaps " + SubmapName(e.a) + " and " + SubmapName(e.b) +
                              " not merged (C = " + strength + "): " + e.status);
      }
    }
  }
  // On Earth: every map placed by the aircraft's GNSS fixes, where the run has them: those the
  // ground received (the merger's gnss_received.csv), else the source's (gnss.csv, which also
  // says where the truth's frame is on Earth).
  nlohmann::json georeference = nullptr;
  info->geo_figures.clear();
  std::error_code ignored;
  // An earlier evaluation's: this one may not place the map.
  for (const char* placed_map : {"map_enu.ply", "map_utm.las"}) fs::remove(dir / "geo" / placed_map, ignored);
  fs::remove_all(dir / "geo" / "colmap_enu", ignored);
  const bool received = fs::exists(dir / "gnss_received.csv");
  if (received || fs::exists(dir / "gnss.csv")) {
    try {
      // The run's own settings (the defaults for a folder without them).
      const GeoReferenceOptions options = fs::exists(dir / "config.yaml")
                                              ? LoadStitchConfig((dir / "config.yaml").string()).merger.georeference
                                              : GeoReferenceOptions();
      if (options.enabled) {
        GnssTrack gnss = ReadGnssCsv((dir / (received ? "gnss_received.csv" : "gnss.csv")).string());
        if (received && fs::exists(dir / "gnss.csv")) {
          const GnssTrack sent = ReadGnssCsv((dir / "gnss.csv").string());
          gnss.ground_truth_enu_origin = sent.ground_truth_enu_origin;
          gnss.source = sent.source + ", as the ground received them";
          if (sent.fixes.size() > gnss.fixes.size()) {
            info->notes.push_back("the ground received " + std::to_string(gnss.fixes.size()) + " of the source's " +
                                  std::to_string(sent.fixes.size()) + " GNSS fixes");
          }
        }
        const RunGeoReference geo =
            GeoReferenceRun(input.poses, evaluation.largest_component, gnss, input.ground_truth, options);
        WriteGeoOutputs((dir / "geo").string(), geo, input.poses);
        if (fs::exists(dir / "map.ply")) {
          try {
            // map.ply is the merger's largest map: its component 0 (submaps.tsv).
            const std::vector<ColouredPoint> map = ReadPly((dir / "map.ply").string());
            WriteMapInEnu((dir / "geo" / "map_enu.ply").string(), geo, 0, map);
            WriteMapLas((dir / "geo" / "map_utm.las").string(), geo, 0, map);
          } catch (const std::exception& e) {  // the trajectory on Earth stands without it
            info->notes.push_back(std::string("geo/map_enu.ply, map_utm.las not written: ") + e.what());
          }
        }
        if (fs::exists(dir / "colmap" / "images.txt")) {
          try {  // the merger's model of its largest map, as map.ply
            WriteColmapModelInEnu((dir / "geo" / "colmap_enu").string(), geo, 0,
                                  ReadColmapModel((dir / "colmap").string()));
          } catch (const std::exception& e) {
            info->notes.push_back(std::string("geo/colmap_enu not written: ") + e.what());
          }
        }
        georeference = geo.ToJson();
        info->geo_figures = geo.Summary();
      }
    } catch (const std::exception& e) {  // the rest of the outputs stand without it
      info->notes.push_back(std::string("not placed on Earth: ") + e.what());
    }
  }
  WriteReport((dir / "report.json").string(), evaluation, info->ToJson(), merges, georeference);
  WriteTrajectoryPlot((dir / "trajectory.png").string(), input, evaluation, info->source);
  return evaluation;
}

}  // namespace stitch
