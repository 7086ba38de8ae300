#include "stitch/config/stitch_config.h"

#include <fstream>
#include <sstream>

#include <gtest/gtest.h>
#include <opencv2/core/utility.hpp>

#include "stitch/testing/temp_dir.h"
#include "stitch/util/options.h"
#include "stitch/util/rng.h"

namespace stitch {
namespace {

TEST(StitchConfig, PartialFileOverridesDefaults) {
  testing::TempDir dir;
  std::ofstream(dir / "run.yaml") << "ingest:\n  pacing: realtime\nsynthetic:\n  flight:\n    num_frames: 200\n";
  const StitchConfig config = LoadStitchConfig(dir / "run.yaml");
  EXPECT_EQ(config.ingest.pacing, "realtime");
  EXPECT_EQ(config.synthetic.flight.num_frames, 200);
  EXPECT_EQ(config.tracker.on_loss, "submap");
}

// Why loading `path` failed; "" when it loaded.
std::string WhyNotLoaded(const std::string& path) {
  try {
    LoadStitchConfig(path);
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

TEST(StitchConfig, TyposAndBadValuesAreErrors) {
  testing::TempDir dir;
  std::ofstream(dir / "typo.yaml") << "ingest:\n  pacnig: realtime\n";
  EXPECT_THROW(LoadStitchConfig(dir / "typo.yaml"), Error);
  std::ofstream(dir / "bad.yaml") << "tracker:\n  on_loss: panic\n";
  EXPECT_NE(WhyNotLoaded(dir / "bad.yaml").find("on_loss"), std::string::npos) << WhyNotLoaded(dir / "bad.yaml");
  std::ofstream(dir / "wait.yaml") << "tracker:\n  live_wait_for_points_s: 5\n";
  EXPECT_NE(WhyNotLoaded(dir / "wait.yaml").find("live_wait_for_points_s"), std::string::npos)
      << "a live tracker waiting seconds for the mapper: " << WhyNotLoaded(dir / "wait.yaml");
  std::ofstream(dir / "geo.yaml") << "merger:\n  georeference:\n    min_fixes: 1\n";
  EXPECT_NE(WhyNotLoaded(dir / "geo.yaml").find("merger.georeference.min_fixes"), std::string::npos)
      << "a map placed on Earth by one fix: " << WhyNotLoaded(dir / "geo.yaml");
  std::ofstream(dir / "frames.yaml") << "bus:\n  frame_url: 239.255.76.67:7668\n";
  EXPECT_NE(WhyNotLoaded(dir / "frames.yaml").find("bus.frame_url"), std::string::npos)
      << "a frame bus that is no URL: " << WhyNotLoaded(dir / "frames.yaml");
  std::ofstream(dir / "section.yaml") << "mystery:\n  a: 1\n";
  EXPECT_THROW(LoadStitchConfig(dir / "section.yaml"), Error);
}

TEST(StitchConfig, SavedConfigLoadsBackIdentically) {
  testing::TempDir dir;
  StitchConfig config;
  config.synthetic.seed = 9;
  config.ingest.encoding = "jpeg";
  SaveStitchConfig(config, dir / "saved.yaml");
  const StitchConfig back = LoadStitchConfig(dir / "saved.yaml");
  EXPECT_EQ(back.synthetic.seed, 9);
  EXPECT_EQ(back.ingest.encoding, "jpeg");
  EXPECT_EQ(DumpOptions(back), DumpOptions(config));
}

TEST(StitchConfig, CommittedDefaultFileMatchesTheCode) {
  // config/default.yaml documents every setting; it must not drift from the code.
  std::ifstream in(std::string(STITCH_SOURCE_DIR) + "/config/default.yaml");
  ASSERT_TRUE(in) << "config/default.yaml is missing (regenerate: build/bin/stitch config > config/default.yaml)";
  std::stringstream text;
  text << in.rdbuf();
  EXPECT_NE(text.str().find(DumpOptions(StitchConfig())), std::string::npos)
      << "config/default.yaml is out of date: regenerate it with build/bin/stitch config > config/default.yaml";
}

// Each process runs OpenCV's image operations on their caller's thread unless told otherwise.
TEST(StitchConfig, TheProcessSettingsSetOpenCvsThreads) {
  const int before = cv::getNumThreads();
  StitchConfig config;
  ApplyProcessSettings(config);
  EXPECT_EQ(cv::getNumThreads(), 1) << "the default: one thread";
  config.opencv_threads = 2;
  ApplyProcessSettings(config);
  EXPECT_EQ(cv::getNumThreads(), 2);
  config.opencv_threads = 0;
  ApplyProcessSettings(config);
  EXPECT_GE(cv::getNumThreads(), 1) << "OpenCV's default";
  EXPECT_THROW(ApplySettings(config, std::vector<std::string>{"opencv_threads=-1"}), Error);
  cv::setNumThreads(before);
}

// A vocabulary of a few words is read without complaint by the services: the summary doubts it.
TEST(StitchConfig, DoubtsAVocabularyOfFewWords) {
  Rng rng(3);
  std::vector<std::vector<Descriptor>> images(20);
  for (auto& image : images) {
    image.resize(40);
    for (Descriptor& d : image) {
      for (uint8_t& byte : d) byte = static_cast<uint8_t>(rng.UniformInt(0, 255));
    }
  }
  VocabularyTrainingOptions tiny;
  tiny.branching = 3;
  tiny.depth = 2;
  const Vocabulary few = Vocabulary::Train(images, tiny);
  const std::string doubt = VocabularyDoubts(few);
  EXPECT_NE(doubt.find("only " + std::to_string(few.num_words()) + " words"), std::string::npos) << doubt;
  testing::TempDir dir;
  few.Save(dir / "tiny.stitchvoc");
  StitchConfig config;
  config.vocabulary = dir / "tiny.stitchvoc";
  EXPECT_EQ(LoadVocabulary(config).num_words(), few.num_words());
  config.vocabulary = "";
  EXPECT_EQ(VocabularyDoubts(LoadVocabulary(config)), "") << "the shipped vocabulary";
}

}  // namespace
}  // namespace stitch

namespace stitch {
namespace {

TEST(StitchConfig, SettingsOverrideTheGivenConfigurationAndAreChecked) {
  StitchConfig base;
  base.tracker.tracking.relocalization_candidates = 5;
  const StitchConfig set = ApplySettings(base,
                                         "tracker.tracking.homography_tracking=false,tracker.tracking.orb.threads=2,"
                                         "tracker.tracking.reference_matching=lsh");
  EXPECT_FALSE(set.tracker.tracking.homography_tracking);
  EXPECT_EQ(set.tracker.tracking.orb.threads, 2);
  EXPECT_EQ(set.tracker.tracking.reference_matching, "lsh");
  EXPECT_EQ(set.tracker.tracking.relocalization_candidates, 5);  // untouched settings keep the given values
  EXPECT_EQ(ApplySettings(base, "").tracker.tracking.relocalization_candidates, 5);
  EXPECT_THROW(ApplySettings(base, "tracker.tracking.reference_matching=kd_tree"), Error);  // checked
  EXPECT_THROW(ApplySettings(base, "tracker.no_such_key=1"), Error);
  EXPECT_THROW(ApplySettings(base, "tracker.tracking.orb.threads"), Error);
  EXPECT_THROW(ApplySettings(base, "tracker..orb=1"), Error);
}

TEST(StitchConfig, FlagsBecomeSettingsOverTheFileAndTextStaysAsGiven) {
  testing::TempDir dir;
  const std::string file = dir / "settings.yaml";
  std::ofstream(file) << "tracker:\n  on_loss: relocalize\nlink:\n  budget_bytes_per_s: 3000\n";
  // A program's own flags are settings after --set's: the last word wins.
  const std::string regex = "uav0/(SUBMAP|SEQUENCE): 'x'";
  const StitchConfig config =
      LoadStitchConfig(file, {"link.budget_bytes_per_s=4000", TextSetting("tracker.on_loss", "submap"),
                              TextSetting("link.forward", regex), NumberSetting("link.loss", 0.05)});
  EXPECT_EQ(config.tracker.on_loss, "submap");
  EXPECT_EQ(config.link.budget_bytes_per_s, 4000);
  EXPECT_EQ(config.link.forward, regex) << "quotes, colons and bars survive";
  EXPECT_DOUBLE_EQ(config.link.loss, 0.05);
  // A value with commas is one setting when given as one.
  EXPECT_EQ(ApplySettings(StitchConfig(), std::vector<std::string>{TextSetting("link.forward", "a,b")}).link.forward,
            "a,b");
  EXPECT_THROW(LoadStitchConfig(file, {TextSetting("tracker.on_loss", "hover")}), Error);
}

TEST(StitchConfig, AnOrbSlamCalibrationSetsTheFeaturesUnderTheCommandLine) {
  const std::string kitti = std::string(STITCH_SOURCE_DIR) + "/src/stitch/io/testdata/orbslam2_kitti00-02.yaml";
  const StitchConfig from_file = LoadStitchConfig("", CommandLineSettings(kitti, "", {}));
  EXPECT_EQ(from_file.tracker.tracking.orb.num_features, 2000);
  EXPECT_DOUBLE_EQ(from_file.tracker.tracking.orb.scale_factor, 1.2);
  EXPECT_EQ(from_file.tracker.tracking.orb.num_levels, 8);
  EXPECT_EQ(from_file.tracker.tracking.orb.fast_threshold, 20);
  EXPECT_EQ(from_file.tracker.tracking.orb.min_fast_threshold, 7);
  // --set wins over the calibration; the vocabulary is a setting like the others.
  const StitchConfig over =
      LoadStitchConfig("", CommandLineSettings(kitti, "/data/ORBvoc.txt", {"tracker.tracking.orb.num_features=1500"}));
  EXPECT_EQ(over.tracker.tracking.orb.num_features, 1500);
  EXPECT_EQ(over.vocabulary, "/data/ORBvoc.txt");
  // A calibration of another layout sets nothing; a value the extractor refuses is an error.
  testing::TempDir dir;
  std::ofstream(dir / "sensor.yaml") << "intrinsics: [458, 457, 367, 248]\nresolution: [752, 480]\n";
  EXPECT_TRUE(OrbSlamFeatureSettings(dir / "sensor.yaml").empty());
  std::ofstream(dir / "zero.yaml") << "%YAML:1.0\nCamera.fx: 500\nORBextractor.nLevels: 0\n";
  EXPECT_THROW(LoadStitchConfig("", CommandLineSettings(dir / "zero.yaml", "", {})), Error);
}

}  // namespace
}  // namespace stitch
