// `stitch run`'s plan, before any process starts: which services, with which arguments, on
// which side of the link, and what it refuses.

#include "tools/stitch/launch/launch_plan.h"

#include <algorithm>
#include <filesystem>

#include <gtest/gtest.h>

#include "stitch/config/stitch_config.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

std::vector<std::string> Names(const LaunchPlan& plan) {
  std::vector<std::string> names;
  for (const PlannedService& s : plan.services) names.push_back(s.name);
  return names;
}

const PlannedService& Service(const LaunchPlan& plan, const std::string& name) {
  for (const PlannedService& s : plan.services) {
    if (s.name == name) return s;
  }
  throw Error("no " + name + " in the plan");
}

// The value after `flag` in a service's arguments ("" when absent).
std::string Argument(const PlannedService& service, const std::string& flag) {
  const auto it = std::find(service.args.begin(), service.args.end(), flag);
  return it == service.args.end() || it + 1 == service.args.end() ? "" : *(it + 1);
}

RunArgs ShortFlight() {
  RunArgs args;
  args.source.max_frames = 20;
  return args;
}

TEST(LaunchPlan, TheDefaultRunStartsTheGroundFirstAndIngestLastOnOneBus) {
  const LaunchPlan plan = PlanRun(ShortFlight(), "/tmp/planned");
  EXPECT_EQ(Names(plan), (std::vector<std::string>{"merger", "mapper", "tracker", "ingest"}));
  EXPECT_FALSE(plan.linked);
  EXPECT_EQ(plan.ground_url, plan.url);
  for (const PlannedService& s : plan.services) {
    EXPECT_EQ(Argument(s, "--lcm-url"), plan.url) << s.name;
    EXPECT_EQ(Argument(s, "--config"), "/tmp/planned/config.yaml") << s.name;
  }
  EXPECT_EQ(Argument(Service(plan, "merger"), "--record"), "/tmp/planned");
  EXPECT_EQ(Argument(Service(plan, "tracker"), "--record"), "/tmp/planned/frames.tsv");
  EXPECT_EQ(Argument(Service(plan, "ingest"), "--record"), "/tmp/planned/ingest.json");
  EXPECT_EQ(Argument(Service(plan, "ingest"), "--max-frames"), "20");
  EXPECT_EQ(Argument(Service(plan, "ingest"), "--failures"), "");  // the default: the ingest's own
  EXPECT_EQ(plan.info.frames_total, 20);
  EXPECT_EQ(plan.info.failures, "4:1,9:1,14:1");  // the default's three gusts, spread over the flight
  EXPECT_EQ(plan.info.frames_unusable, 3);
  // The camera's frames on a bus of their own, which only the ingest and the tracker open.
  EXPECT_EQ(plan.config.bus.frame_url.rfind("udpm://", 0), 0u) << plan.config.bus.frame_url;
  EXPECT_NE(plan.config.bus.frame_url, plan.url);
}

// A bus the user names is the frames' bus too (their own services may listen for frames there),
// unless the config names one for them.
TEST(LaunchPlan, ABusTheUserNamesCarriesTheFramesUnlessTheConfigSaysOtherwise) {
  RunArgs args = ShortFlight();
  args.lcm_url = "udpm://239.255.76.67:7667?ttl=0";
  EXPECT_EQ(PlanRun(args, "/tmp/planned").config.bus.frame_url, "");
  args.settings = {"bus.frame_url=udpm://239.255.76.67:7668?ttl=0"};
  EXPECT_EQ(PlanRun(args, "/tmp/planned").config.bus.frame_url, "udpm://239.255.76.67:7668?ttl=0");
}

// ORB-SLAM settings set the extractor, and a --set of the same key wins: the note says so
// (it named the file's value while the --set one ran).
TEST(LaunchPlan, TheNoteOfAnOrbSlamSettingSaysWhenASetOverridesIt) {
  RunArgs args = ShortFlight();
  args.source.calibration_path = std::string(STITCH_SOURCE_DIR) + "/src/stitch/io/testdata/orbslam2_kitti00-02.yaml";
  args.settings = {"tracker.tracking.orb.num_features=1500"};
  const LaunchPlan plan = PlanRun(args, "/tmp/planned");
  EXPECT_EQ(plan.config.tracker.tracking.orb.num_features, 1500);
  const auto note = std::find_if(plan.info.notes.begin(), plan.info.notes.end(),
                                 [](const std::string& n) { return n.find("num_features=2000") != std::string::npos; });
  ASSERT_NE(note, plan.info.notes.end());
  EXPECT_NE(note->find("overridden by --set tracker.tracking.orb.num_features=1500"), std::string::npos) << *note;
  const auto scale = std::find_if(plan.info.notes.begin(), plan.info.notes.end(),
                                  [](const std::string& n) { return n.find("scale_factor=") != std::string::npos; });
  ASSERT_NE(scale, plan.info.notes.end());
  EXPECT_EQ(scale->find("overridden"), std::string::npos) << *scale;
}

TEST(LaunchPlan, ALinkPutsTheMergerOnABusOfItsOwnBehindTwoBridgesThatNameEachOther) {
  RunArgs args = ShortFlight();
  args.link = true;
  args.viewer = true;
  args.journal = true;
  const LaunchPlan plan = PlanRun(args, "/tmp/planned");
  EXPECT_EQ(Names(plan), (std::vector<std::string>{"merger", "link-ground", "link-aircraft", "viewer", "mapper",
                                                   "tracker", "ingest"}));
  EXPECT_NE(plan.ground_url, plan.url);
  const PlannedService& ground = Service(plan, "link-ground");
  const PlannedService& air = Service(plan, "link-aircraft");
  EXPECT_EQ(Argument(ground, "--peer"), Argument(air, "--listen"));
  EXPECT_EQ(Argument(air, "--peer"), Argument(ground, "--listen"));
  EXPECT_EQ(Argument(ground, "--accept"), Argument(air, "--forward"));
  EXPECT_EQ(Argument(ground, "--key"), "/tmp/planned/link.key");  // authenticated, with a key of the run's
  EXPECT_EQ(plan.link_key, "/tmp/planned/link.key");
  for (const char* name : {"merger", "link-ground", "viewer"}) {
    EXPECT_TRUE(Service(plan, name).on_ground) << name;
    EXPECT_EQ(Argument(Service(plan, name), "--lcm-url"), plan.ground_url) << name;
  }
  for (const char* name : {"link-aircraft", "mapper", "tracker", "ingest"}) {
    EXPECT_FALSE(Service(plan, name).on_ground) << name;
    EXPECT_EQ(Argument(Service(plan, name), "--lcm-url"), plan.url) << name;
  }
  EXPECT_EQ(Argument(Service(plan, "merger"), "--state"), "/tmp/planned/merger");
  EXPECT_EQ(plan.viewer_url, "http://127.0.0.1:8080/");
  EXPECT_TRUE(plan.viewer_token.empty()) << "on loopback the page needs no token";
  EXPECT_NE(plan.info.link.find("authenticated"), std::string::npos) << plan.info.link;
}

// The tracker unrolls a rolling shutter by the readout the source states: the synthetic flight's
// camera, per row of the frames it sees; a value set by hand (0: a global shutter) stays.
TEST(LaunchPlan, TheTrackerTakesTheSourcesRollingShutterUnlessSetByHand) {
  RunArgs args = ShortFlight();
  EXPECT_EQ(PlanRun(args, "/tmp/planned").config.tracker.tracking.rolling_shutter_line_us, 0);
  args.settings = {"synthetic.camera.rolling_shutter_line_us=40"};
  EXPECT_EQ(PlanRun(args, "/tmp/planned").config.tracker.tracking.rolling_shutter_line_us, 40);
  args.settings = {"synthetic.camera.rolling_shutter_line_us=40", "synthetic.width=1920", "synthetic.height=1080",
                   "synthetic.focal_px=1350"};
  const LaunchPlan reduced = PlanRun(args, "/tmp/planned");
  EXPECT_NEAR(reduced.config.tracker.tracking.rolling_shutter_line_us, 40.0 * 1080 / reduced.source.camera.height(),
              1e-9)
      << "frames reduced to " << reduced.source.camera.height() << " rows";
  args.settings = {"synthetic.camera.rolling_shutter_line_us=40", "tracker.tracking.rolling_shutter_line_us=0"};
  EXPECT_EQ(PlanRun(args, "/tmp/planned").config.tracker.tracking.rolling_shutter_line_us, 0);
}

// The synthetic flight's camera looks straight down from a gimbal, and says so: its maps placed by
// GNSS are levelled by their cameras (merger.georeference.level_by_camera auto); a tilted camera,
// a dataset, or a value set by hand is left as it is.
TEST(LaunchPlan, AMountTheSourceStatesLevelsTheMapsItsFixesPlace) {
  RunArgs args = ShortFlight();
  const GeoReferenceOptions nadir = PlanRun(args, "/tmp/planned").config.merger.georeference;
  EXPECT_EQ(nadir.level_by_camera, "true");
  EXPECT_EQ(nadir.camera_up_axis, "-z");
  args.settings = {"synthetic.flight.camera_pitch_deg=45"};
  const GeoReferenceOptions oblique = PlanRun(args, "/tmp/planned").config.merger.georeference;
  EXPECT_EQ(oblique.level_by_camera, "false");
  EXPECT_EQ(oblique.camera_up_axis, "auto");
  args.settings = {"merger.georeference.level_by_camera=false"};
  EXPECT_EQ(PlanRun(args, "/tmp/planned").config.merger.georeference.level_by_camera, "false");
  args.settings = {"merger.georeference.camera_up_axis=-y"};
  EXPECT_EQ(PlanRun(args, "/tmp/planned").config.merger.georeference.camera_up_axis, "-y") << "stated by hand";
  args.settings = {"merger.georeference.level_by_camera=maybe"};
  EXPECT_THROW(PlanRun(args, "/tmp/planned"), Error);
}

// A viewer off this machine's loopback gets an access token made for the run, beside its outputs;
// the config the services read names it, and the address printed carries it.
TEST(LaunchPlan, AViewerOffLoopbackGetsAnAccessTokenOfTheRuns) {
  testing::TempDir dir;
  RunArgs args = ShortFlight();
  args.viewer = true;
  args.settings = {"viewer.bind_address=0.0.0.0"};
  const std::string out = dir / "run";
  const LaunchPlan plan = PlanRun(args, out);
  EXPECT_EQ(plan.viewer_token, out + "/viewer.token");
  EXPECT_EQ(plan.config.viewer.access_token_file, plan.viewer_token);
  PrepareRunFolder(plan);
  EXPECT_EQ(std::filesystem::status(plan.viewer_token).permissions() & std::filesystem::perms::group_read,
            std::filesystem::perms::none);
  const std::string address = ViewerAddress(plan);
  ASSERT_EQ(address.rfind("http://0.0.0.0:8080/?token=", 0), 0u) << address;
  EXPECT_EQ(address.size(), std::string("http://0.0.0.0:8080/?token=").size() + 64);
  EXPECT_EQ(LoadStitchConfig(out + "/config.yaml", {}).viewer.access_token_file, plan.viewer_token);
}

TEST(LaunchPlan, FlagsBecomeSettingsOverTheFile) {
  RunArgs args = ShortFlight();
  args.on_loss = "relocalize";
  args.pacing = "realtime";
  args.settings = {"mapper.stop_linger_s=3"};
  const LaunchPlan plan = PlanRun(args, "/tmp/planned");
  EXPECT_EQ(plan.config.tracker.on_loss, "relocalize");
  EXPECT_EQ(plan.config.ingest.pacing, "realtime");
  EXPECT_EQ(plan.info.pacing, "realtime");
  // At the camera's rate the ground's merger yields the CPU to the aircraft's services.
  EXPECT_EQ(Service(plan, "merger").niceness, kGroundNiceness);
  EXPECT_EQ(Service(plan, "tracker").niceness, 0);
  EXPECT_EQ(Service(PlanRun(ShortFlight(), "/tmp/planned"), "merger").niceness, 0) << "lockstep";
  EXPECT_EQ(plan.config.mapper.delivery.stop_linger_s, 3);
  // The mapper's grace follows its delivery settings: linger and link drain, and a minute more.
  EXPECT_EQ(StopGraceSeconds(plan, "mapper"), std::max(120.0, 300.0 + 3.0 + 60.0));
  EXPECT_EQ(StopGraceSeconds(plan, "tracker"), 15.0);
}

TEST(LaunchPlan, RefusesWhatNoRunCanTake) {
  RunArgs args = ShortFlight();
  args.source.start_frame = -1;
  EXPECT_THROW(PlanRun(args, "/tmp/planned"), Error);
  args = ShortFlight();
  args.vocabulary = "/nonexistent/voc.stitchvoc";
  EXPECT_THROW(PlanRun(args, "/tmp/planned"), Error);
  args = ShortFlight();
  args.agent = "bad agent";
  EXPECT_THROW(PlanRun(args, "/tmp/planned"), Error);
  args = ShortFlight();
  args.settings = {"mapper.stop_linger_s=-1"};
  EXPECT_THROW(PlanRun(args, "/tmp/planned"), Error);
}

}  // namespace
}  // namespace stitch
