#pragma once
// The whole configuration of a stitch deployment, one section per module, loaded in one place.
// A YAML file may set any subset; unknown keys are errors; the resolved configuration is written
// to each run's folder (config.yaml). `stitch config` prints the defaults with their help.

#include <string>
#include <vector>

#include "stitch/config/bus_options.h"
#include "stitch/config/ingest_options.h"
#include "stitch/config/link_options.h"
#include "stitch/config/mapper_options.h"
#include "stitch/config/tracker_options.h"
#include "stitch/config/viewer_options.h"
#include "stitch/features/vocabulary.h"
#include "stitch/merging/merger_options.h"
#include "stitch/pipeline/pipeline_options.h"
#include "stitch/synthetic/synthetic_sequence.h"

namespace stitch {

struct StitchConfig {
  std::string vocabulary;  // empty: the vocabulary shipped with stitch
  // Threads one OpenCV image operation (resize, blur, FAST, optical flow) may use in each process
  // (0: OpenCV's default, every core). 1: the services share a small computer's cores as
  // processes; OpenCV's own helper threads only wait and spin for them (docs/speed.md).
  int opencv_threads = 1;
  SyntheticOptions synthetic;
  IngestOptions ingest;
  TrackerOptions tracker;
  MapperOptions mapper;
  MergerOptions merger;
  LinkOptions link;
  ViewerOptions viewer;
  BusOptions bus;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("vocabulary", vocabulary, "bag-of-words vocabulary file (empty: the one shipped with stitch)");
    v("opencv_threads", opencv_threads,
      "threads one OpenCV image operation may use in each process (0: OpenCV's default, every core)");
    v("synthetic", synthetic, "the embedded default flight");
    v("ingest", ingest, "frame source service");
    v("tracker", tracker, "tracking service");
    v("mapper", mapper, "local mapping service");
    v("merger", merger, "submap merging service");
    v("link", link, "link bridge between the aircraft's and the ground's networks (stitch-link)");
    v("viewer", viewer, "the ground's live web page (stitch-viewer)");
    v("bus", bus, "this side's LCM bus, the same for each of its services");
  }
  bool Check(std::string* why) const {
    if (opencv_threads < 0 || opencv_threads > 64) {
      if (why) *why = "opencv_threads must be in [0, 64]";
      return false;
    }
    return synthetic.Check(why) && ingest.Check(why) && tracker.Check(why) && mapper.Check(why) && merger.Check(why) &&
           link.Check(why) && viewer.Check(why) && bus.Check(why);
  }
  // The algorithms' settings, for running them inline (no bus).
  PipelineOptions pipeline() const { return {tracker.tracking, tracker.on_loss, mapper.mapping, merger}; }
};

// The vocabulary the configuration names (or the shipped default); throws stitch::Error. Logs a
// warning with VocabularyDoubts.
Vocabulary LoadVocabulary(const StitchConfig& config);
// What makes a vocabulary a poor one for retrieval, as a sentence ("" when nothing): too few words.
std::string VocabularyDoubts(const Vocabulary& vocabulary);
std::string DefaultVocabularyPath();

// What the configuration sets for the whole process it runs in: OpenCV's threads
// (opencv_threads). Each service's and each in-process run's first step.
void ApplyProcessSettings(const StitchConfig& config);

// Defaults when `path` is empty. Throws stitch::Error naming the file and key on any problem.
StitchConfig LoadStitchConfig(const std::string& path);
// The file (or the defaults), then `settings` ("key.path=value" each) over it: the one way every
// program turns its command line into settings (--config FILE, --set KEY=VALUE, and its own
// flags, each a setting). Throws stitch::Error naming the file, setting and key.
StitchConfig LoadStitchConfig(const std::string& path, const std::vector<std::string>& settings);
void SaveStitchConfig(const StitchConfig& config, const std::string& path);
// `config` with settings applied, each "key.path=value" (e.g.
// "tracker.tracking.homography_tracking=false"; the value is YAML); checked like a file. Throws
// stitch::Error.
StitchConfig ApplySettings(StitchConfig config, const std::vector<std::string>& settings);
// The same from "key=value[,key=value...]" (values without commas).
StitchConfig ApplySettings(StitchConfig config, const std::string& settings);
// The feature extractor's settings an ORB-SLAM settings file states (ORBextractor.nFeatures,
// scaleFactor, nLevels, iniThFAST, minThFAST), as settings of tracker.tracking.orb; none for a
// calibration of another layout. A launcher given such a file (--calib) applies them over the
// settings file and under its own --set. Throws stitch::Error for a value that is no number.
std::vector<std::string> OrbSlamFeatureSettings(const std::string& calibration_path);
// The settings a launcher's command line means, in the order they apply (the later win): an
// ORB-SLAM calibration's feature settings (OrbSlamFeatureSettings; none for an empty path), the
// vocabulary (when not empty), then `settings` (--set and the launcher's own flags).
std::vector<std::string> CommandLineSettings(const std::string& calibration_path, const std::string& vocabulary,
                                             const std::vector<std::string>& settings);
// A setting giving `key` the text `value` as it is (quoted for YAML), or a number.
std::string TextSetting(const std::string& key, const std::string& value);
std::string NumberSetting(const std::string& key, double value);

}  // namespace stitch
