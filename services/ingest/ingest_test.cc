// The ingest service against a real tracker service and plain subscribers, in-process over
// memq:// and over UDP multicast.

#include "services/ingest/ingest_service.h"

#include <unistd.h>

#include <fstream>
#include <functional>
#include <initializer_list>
#include <limits>
#include <map>
#include <mutex>
#include <optional>
#include <set>
#include <thread>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "services/common/convert.h"
#include "services/tracker/tracker_service.h"
#include "stitch/frame_ack_t.hpp"
#include "stitch/gnss_fix_t.hpp"
#include "stitch/records/frame_record.h"
#include "stitch/source/read_ahead.h"
#include "stitch/source/source.h"
#include "stitch/testing/temp_dir.h"
#include "stitch/tracking_status_t.hpp"

namespace stitch {
namespace {

using namespace std::chrono_literals;

SourceSpec ShortFlight(int frames) {
  SourceSpec spec;
  spec.synthetic.width = 320;
  spec.synthetic.height = 240;
  spec.synthetic.focal_px = 225;
  spec.synthetic.flight.num_frames = frames;
  spec.synthetic.flight.num_strips = 1;
  spec.synthetic.flight.strip_length_m = 40;
  spec.synthetic.world.num_buildings = 5;
  spec.failures = "none";
  return spec;
}

// Receives frames (decoded) and tracking statuses.
struct Recorder {
  std::mutex mutex;
  std::map<int, cv::Mat> frames;
  std::vector<stitch::tracking_status_t> statuses;
  int frame_messages = 0;
  // Frames ('F') and GNSS fixes ('G') with their times, in the order they came.
  std::vector<std::pair<char, int64_t>> order;

  void Subscribe(bus::Subscriber* subscriber, const std::string& agent) {
    subscriber->Subscribe<stitch::gnss_fix_t>(bus::Channel(agent, bus::kGnss),
                                              [this](std::unique_ptr<stitch::gnss_fix_t> f, const std::string&) {
                                                std::lock_guard<std::mutex> lock(mutex);
                                                order.emplace_back('G', f->t_ns);
                                              });
    subscriber->Subscribe<stitch::frame_t>(bus::Channel(agent, bus::kFrame),
                                           [this](std::unique_ptr<stitch::frame_t> f, const std::string&) {
                                             std::lock_guard<std::mutex> lock(mutex);
                                             ++frame_messages;
                                             order.emplace_back('F', f->t_ns);
                                             if (f->num_bytes > 0) frames[f->frame_index] = DecodeImage(*f);
                                           });
    subscriber->Subscribe<stitch::tracking_status_t>(
        bus::Channel(agent, bus::kTrackingStatus),
        [this](std::unique_ptr<stitch::tracking_status_t> s, const std::string&) {
          std::lock_guard<std::mutex> lock(mutex);
          statuses.push_back(*s);
        });
  }
};

const Vocabulary& TestVocabulary() {
  static const Vocabulary* vocabulary =
      new Vocabulary(Vocabulary::Load(std::string(STITCH_SOURCE_DIR) + "/vocabulary/default.stitchvoc"));
  return *vocabulary;
}

// A tracker alone, without a mapper to wait for.
TrackerOptions TrackerAlone() {
  TrackerOptions options;
  options.wait_for_mapper = false;
  return options;
}

IngestOptions Lockstep() {
  IngestOptions options;
  options.pacing = "lockstep";
  options.wait_for_tracker_s = 5;
  return options;
}

// Ingest, a real tracker service and a recorder on one memq:// bus, as in a single process.
struct InProcessRun {
  explicit InProcessRun(const IngestOptions& options, const std::string& record_path = "")
      : lcm(bus::OpenLcm("memq://")),
        publisher(lcm.get(), "uav0"),
        ingest(lcm.get(), "memq://", &publisher, options),
        tracker(lcm.get(), &publisher, TrackerAlone(), &TestVocabulary(), record_path),
        subscriber(lcm.get()),
        dispatcher(lcm.get()) {
    recorder.Subscribe(&subscriber, "uav0");
  }

  IngestSummary Play(const SourceSpec& spec) {
    dispatcher.Start();
    tracker.Start();
    FailureSchedule spoil;
    auto sequence = OpenSource(spec, &spoil);
    std::atomic<bool> stop{false};
    const IngestSummary summary = ingest.Play(*sequence, spoil, stop, SourceGnss(spec).fixes);
    tracker.Stop();
    dispatcher.Stop();
    return summary;
  }

  std::unique_ptr<lcm::LCM> lcm;
  bus::Publisher publisher;
  IngestService ingest;
  TrackerService tracker;
  Recorder recorder;
  bus::Subscriber subscriber;
  bus::Dispatcher dispatcher;
};

// An image folder of `count` frames (160x120) with a calibration, for dataset tests.
std::string ImageFolder(const testing::TempDir& dir, int count, bool random_texture) {
  std::filesystem::create_directories(dir.path() / "images");
  for (int i = 0; i < count; ++i) {
    cv::Mat image(120, 160, CV_8U, cv::Scalar(50 * i));
    if (random_texture) cv::randu(image, 0, 255);
    cv::imwrite(dir / ("images/" + std::to_string(i) + ".png"), image);
  }
  std::ofstream(dir / "images/camera.yaml") << "Camera.fx: 150\nCamera.fy: 150\nCamera.cx: 79.5\nCamera.cy: 59.5\n";
  return dir / "images";
}

TEST(Ingest, LockstepWithTheTrackerDeliversEveryFrameOnceInProcess) {
  testing::TempDir dir;
  InProcessRun run(Lockstep(), dir / "frames.tsv");
  const IngestSummary summary = run.Play(ShortFlight(15));
  Recorder& recorder = run.recorder;
  TrackerService& tracker = run.tracker;

  EXPECT_EQ(summary.frames_published, 15);
  EXPECT_EQ(summary.frames_unacked, 0);
  EXPECT_EQ(tracker.frames_tracked(), 15);
  ASSERT_EQ(recorder.statuses.size(), 15u);
  for (int i = 0; i < 15; ++i) EXPECT_EQ(recorder.statuses[i].frame_index, i);
  // Every frame arrived as rendered.
  FailureSchedule spoil;
  auto again = OpenSource(ShortFlight(15), &spoil);
  SequenceFrame frame;
  while (again->Next(&frame)) {
    ASSERT_TRUE(recorder.frames.count(frame.index));
    EXPECT_EQ(cv::norm(recorder.frames[frame.index], frame.image, cv::NORM_INF), 0) << frame.index;
  }
  // The tracker's record has a line per frame.
  EXPECT_EQ(ReadFrameRecords(dir / "frames.tsv").size(), 15u);
  // The synthetic receiver's fixes (5 Hz over 0.7 s: 4), each just before the first frame at or
  // after its time.
  EXPECT_EQ(summary.gnss_fixes_published, 4);
  int fixes = 0;
  int64_t latest_frame = -1;
  for (size_t i = 0; i < recorder.order.size(); ++i) {
    const auto& [kind, t_ns] = recorder.order[i];
    if (kind == 'F') {
      latest_frame = std::max(latest_frame, t_ns);
      continue;
    }
    ++fixes;
    EXPECT_LT(latest_frame, t_ns) << "the fix at " << t_ns << " came after a frame at " << latest_frame;
    const auto next_frame = std::find_if(recorder.order.begin() + i, recorder.order.end(),
                                         [](const auto& event) { return event.first == 'F'; });
    if (next_frame != recorder.order.end()) {
      EXPECT_GE(next_frame->second, t_ns);
    }
  }
  EXPECT_EQ(fixes, 4);
}

// Ingest never sends an acknowledged frame again, so a tracker killed right after an ack must
// already have that frame's line on disk: the record is read at each ack, as a crash would leave it.
TEST(Ingest, EveryAcknowledgedFrameIsAlreadyInTheTrackersRecord) {
  testing::TempDir dir;
  const std::string path = dir / "frames.tsv";
  InProcessRun run(Lockstep(), path);
  std::mutex mutex;
  std::vector<std::pair<int, int>> acked_and_on_disk;
  run.subscriber.Subscribe<stitch::frame_ack_t>(bus::Channel("uav0", bus::kFrameAck),
                                                [&](std::unique_ptr<stitch::frame_ack_t> ack, const std::string&) {
                                                  const int on_disk = static_cast<int>(ReadFrameRecords(path).size());
                                                  std::lock_guard<std::mutex> lock(mutex);
                                                  acked_and_on_disk.emplace_back(ack->frame_index, on_disk);
                                                });
  run.Play(ShortFlight(8));
  // Each frame acked; a frame re-sent because its ack came late (a slow build) is acked again.
  std::set<int> acked;
  for (const auto& [frame, on_disk] : acked_and_on_disk) {
    acked.insert(frame);
    EXPECT_GE(on_disk, frame + 1) << "frame " << frame;
  }
  EXPECT_EQ(acked, (std::set<int>{0, 1, 2, 3, 4, 5, 6, 7}));
}

// Real-time pacing, the 20 Hz flight played at 80 Hz, JPEG frames.
IngestOptions RealtimeAt4x() {
  IngestOptions options;
  options.pacing = "realtime";
  options.speed = 4.0;
  options.encoding = "jpeg";
  options.wait_for_tracker_s = 0;  // no tracker here
  return options;
}

TEST(Ingest, RealtimeOverUdpMulticastPublishesAtTheCameraRate) {
  const std::string url = bus::UnusedLocalUdpUrl();
  auto lcm = bus::OpenLcm(url);
  bus::Publisher publisher(lcm.get(), "uav1");
  IngestService ingest(lcm.get(), url, &publisher, RealtimeAt4x());
  Recorder recorder;
  bus::Subscriber subscriber(lcm.get());
  recorder.Subscribe(&subscriber, "uav1");
  bus::Dispatcher dispatcher(lcm.get());
  dispatcher.Start();
  FailureSchedule spoil;
  auto sequence = OpenSource(ShortFlight(20), &spoil);
  std::atomic<bool> stop{false};
  const IngestSummary summary = ingest.Play(*sequence, spoil, stop);
  std::this_thread::sleep_for(200ms);
  dispatcher.Stop();
  EXPECT_EQ(summary.frames_published, 20);
  // 19 frame intervals of 50 ms at 4x speed: about 0.24 s, never less.
  EXPECT_GE(summary.seconds, 0.23);
  // Waiting for no ack: one ack timeout (0.25 s) per frame would take 5 s. (A sanitizer build
  // beside another test took 2.1 s to render and send the 20 frames.)
  EXPECT_LT(summary.seconds, 4.0);
  EXPECT_GE(recorder.frames.size(), 18u) << "frames lost on loopback multicast";
}

// A source slower than its camera: each frame takes `delay` to come out.
class SlowSequence : public ImageSequence {
 public:
  SlowSequence(std::unique_ptr<ImageSequence> inner, std::chrono::milliseconds delay)
      : inner_(std::move(inner)), delay_(delay) {}
  std::string description() const override { return "slow " + inner_->description(); }
  int size() const override { return inner_->size(); }
  const Camera& camera() const override { return inner_->camera(); }
  double nominal_fps() const override { return inner_->nominal_fps(); }
  const Trajectory& ground_truth() const override { return inner_->ground_truth(); }
  bool Next(SequenceFrame* frame) override {
    std::this_thread::sleep_for(delay_);
    return inner_->Next(frame);
  }

 private:
  std::unique_ptr<ImageSequence> inner_;
  std::chrono::milliseconds delay_;
};

// Real-time playback of a source that cannot keep its camera's pace: the frames it sends late are
// counted (the run played slower than the camera).
TEST(Ingest, FramesASlowSourceSendsLateAreCounted) {
  const std::string url = bus::UnusedLocalUdpUrl();
  auto lcm = bus::OpenLcm(url);
  bus::Publisher publisher(lcm.get(), "uav1");
  IngestService ingest(lcm.get(), url, &publisher, RealtimeAt4x());  // a frame every 12.5 ms
  FailureSchedule spoil;
  SlowSequence slow(OpenSource(ShortFlight(10), &spoil), 60ms);
  std::atomic<bool> stop{false};
  const IngestSummary summary = ingest.Play(slow, spoil, stop);
  EXPECT_EQ(summary.frames_published, 10);
  // Each frame 60 ms after the one before against 12.5 ms: from the second on, more than a frame
  // late (the first sets the camera's start).
  EXPECT_GE(summary.frames_late, 8);
  EXPECT_GT(summary.most_late_s, 0.3);
}

// A recorded source whose reading is slow now and then, not on average: 20 small frames at 40 fps
// (25 ms apart), every fourth taking 60 ms to read (15 ms a frame on average).
class JitterySequence : public ImageSequence {
 public:
  std::string description() const override { return "jittery"; }
  int size() const override { return 20; }
  const Camera& camera() const override { return camera_; }
  double nominal_fps() const override { return 40; }
  const Trajectory& ground_truth() const override { return ground_truth_; }
  bool Next(SequenceFrame* frame) override {
    if (next_ == size()) return false;
    if (next_ % 4 == 3) std::this_thread::sleep_for(60ms);
    frame->index = next_;
    frame->t_ns = next_ * 25'000'000LL;
    frame->image = cv::Mat(48, 64, CV_8UC1, cv::Scalar(next_));
    ++next_;
    return true;
  }

 private:
  Camera camera_ = Camera::Pinhole(64, 48, 50, 50, 32, 24);
  Trajectory ground_truth_;
  int next_ = 0;
};

// Played at its camera's rate, the slow frames of such a source are sent more than a frame late
// when each is read as it is due; read ahead, none is, and the frames are the same.
TEST(Ingest, ASourceReadAheadSendsItsSlowFramesOnTime) {
  const std::string url = bus::UnusedLocalUdpUrl();
  auto lcm = bus::OpenLcm(url);
  bus::Publisher publisher(lcm.get(), "uav1");
  IngestOptions options = RealtimeAt4x();
  options.speed = 1.0;
  IngestService ingest(lcm.get(), url, &publisher, options);
  std::atomic<bool> stop{false};
  JitterySequence as_due;
  const IngestSummary late = ingest.Play(as_due, FailureSchedule(), stop);
  EXPECT_EQ(late.frames_published, 20);
  EXPECT_GE(late.frames_late, 4) << "each slow frame but the first is ready 35 ms after its time";
  auto ahead = ReadAhead(std::make_unique<JitterySequence>(), 8);
  const IngestSummary on_time = ingest.Play(*ahead, FailureSchedule(), stop);
  EXPECT_EQ(on_time.frames_published, 20);
  EXPECT_EQ(on_time.frames_late, 0);
}

TEST(Ingest, FailureScheduleSpoilsExactlyTheScheduledDatasetFrames) {
  testing::TempDir dir;
  SourceSpec spec;
  spec.dataset_path = ImageFolder(dir, 6, true);
  spec.failures = "2:2";
  IngestOptions options = Lockstep();
  options.failure_style = "black";
  InProcessRun run(options);
  const IngestSummary summary = run.Play(spec);
  Recorder& recorder = run.recorder;
  EXPECT_EQ(summary.frames_replaced, 2);
  ASSERT_EQ(recorder.frames.size(), 6u);
  for (int i = 0; i < 6; ++i) {
    const bool black = cv::countNonZero(recorder.frames[i]) == 0;
    EXPECT_EQ(black, i == 2 || i == 3) << "frame " << i;
  }
}

TEST(Ingest, UnreadableFramesAreSentEmptyAndReportedByTheTracker) {
  testing::TempDir dir;
  SourceSpec spec;
  spec.dataset_path = ImageFolder(dir, 3, false);
  std::ofstream(dir / "images/1.png") << "garbage";
  InProcessRun run(Lockstep());
  const IngestSummary summary = run.Play(spec);
  Recorder& recorder = run.recorder;
  EXPECT_EQ(summary.frames_unreadable, 1);
  ASSERT_EQ(recorder.statuses.size(), 3u);
  EXPECT_EQ(recorder.statuses[1].reason, stitch::tracking_status_t::REASON_UNDECODABLE_FRAME);
  EXPECT_EQ(recorder.statuses[1].state, stitch::tracking_status_t::STATE_SKIPPED);
}

TEST(Ingest, LockstepWithoutATrackerFailsWithAClearError) {
  auto lcm = bus::OpenLcm("memq://");
  bus::Publisher publisher(lcm.get(), "uav0");
  IngestOptions options = Lockstep();
  options.wait_for_tracker_s = 0.2;
  IngestService ingest(lcm.get(), "memq://", &publisher, options);
  bus::Dispatcher dispatcher(lcm.get());
  dispatcher.Start();
  FailureSchedule spoil;
  auto sequence = OpenSource(ShortFlight(3), &spoil);
  std::atomic<bool> stop{false};
  try {
    ingest.Play(*sequence, spoil, stop);
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("no tracker"), std::string::npos) << e.what();
  }
}

// Plays four frames in lockstep against a tracker stand-in that answers the n-th copy of frame
// `frame` with the ack `answer(frame, copy)` returns (none when it returns nullopt).
IngestSummary PlayAgainstAStandIn(
    const std::function<std::optional<stitch::frame_ack_t>(const stitch::frame_t&, int)>& answer) {
  auto lcm = bus::OpenLcm("memq://");
  bus::Publisher publisher(lcm.get(), "uav0");
  IngestOptions options = Lockstep();
  options.ack_timeout_s = 0.05;
  IngestService ingest(lcm.get(), "memq://", &publisher, options);
  std::map<int, int> copies;
  bus::Subscriber subscriber(lcm.get());
  subscriber.Subscribe<stitch::frame_t>(bus::Channel("uav0", bus::kFrame),
                                        [&](std::unique_ptr<stitch::frame_t> f, const std::string&) {
                                          if (auto ack = answer(*f, ++copies[f->frame_index])) {
                                            publisher.Publish(bus::Channel("uav0", bus::kFrameAck), &*ack);
                                          }
                                        });
  Heartbeat heartbeat(&publisher, "tracker", [] { return Heartbeat::Counts{}; });
  bus::Dispatcher dispatcher(lcm.get());
  dispatcher.Start();
  heartbeat.Start();
  heartbeat.SetState(stitch::service_status_t::STATE_RUNNING);
  FailureSchedule spoil;
  auto sequence = OpenSource(ShortFlight(4), &spoil);
  std::atomic<bool> stop{false};
  const IngestSummary summary = ingest.Play(*sequence, spoil, stop);
  heartbeat.Stop();
  dispatcher.Stop();
  return summary;
}

stitch::frame_ack_t AckOf(const stitch::frame_t& frame, int64_t session) {
  stitch::frame_ack_t ack{};
  ack.frame_index = frame.frame_index;
  ack.frame_session = session;
  return ack;
}

TEST(Ingest, LostAcksAreRecoveredByResending) {
  // The first copy of every frame goes unanswered, as if its ack had been lost.
  const IngestSummary summary = PlayAgainstAStandIn([](const stitch::frame_t& f, int copy) {
    return copy < 2 ? std::nullopt : std::optional(AckOf(f, f.header.sender_session));
  });
  EXPECT_EQ(summary.frames_published, 4);
  EXPECT_EQ(summary.resends, 4);
  EXPECT_EQ(summary.frames_unacked, 0);
}

TEST(Ingest, AcksOfAnotherIngestsFramesDoNotCount) {
  // The first copy of every frame is answered with an ack naming another sender's frames (an
  // earlier run, a second ingest); only the re-sends' own acks let the ingest go on.
  const IngestSummary summary = PlayAgainstAStandIn([](const stitch::frame_t& f, int copy) {
    return std::optional(AckOf(f, f.header.sender_session + (copy < 2 ? 1 : 0)));
  });
  EXPECT_EQ(summary.frames_published, 4);
  EXPECT_EQ(summary.resends, 4);  // each frame waited for its own ack
  EXPECT_EQ(summary.frames_unacked, 0);
}

// The security issue's row: forged acks (any sender can publish on FRAME_ACK, and the frames'
// session is on the bus for all to read) made a lockstep ingest skip its waits, 126 frames
// dropped by the tracker, and report "0 unacknowledged". An ack for a frame not sent yet is refused.
TEST(Ingest, AnAckForAFrameNotSentYetIsRefused) {
  // The first copy of frame 0 is answered only by a forged ack for frame 2^31-1; the first copy
  // of every other frame goes unanswered (a busy tracker); re-sends get their real acks.
  const IngestSummary summary = PlayAgainstAStandIn([](const stitch::frame_t& f, int copy) {
    if (copy >= 2) return std::optional(AckOf(f, f.header.sender_session));
    if (f.frame_index != 0) return std::optional<stitch::frame_ack_t>();
    stitch::frame_ack_t forged = AckOf(f, f.header.sender_session);
    forged.frame_index = std::numeric_limits<int32_t>::max();
    return std::optional(forged);
  });
  EXPECT_EQ(summary.frames_published, 4);
  EXPECT_EQ(summary.resends, 4);  // each frame waited for its own ack
  EXPECT_EQ(summary.frames_unacked, 0);
  EXPECT_EQ(summary.acks_refused, 1);
}

// Publishes `frame` numbered each of `indices` in turn, 30 ms apart.
void PublishAs(bus::Publisher* publisher, stitch::frame_t* frame, std::initializer_list<int> indices) {
  for (int index : indices) {
    frame->frame_index = index;
    publisher->Publish(bus::Channel("uav0", bus::kFrame), frame);
    std::this_thread::sleep_for(30ms);
  }
}

TEST(Tracker, DuplicateFramesAreAckedAgainButTrackedOnce) {
  auto lcm = bus::OpenLcm("memq://");
  bus::Publisher publisher(lcm.get(), "uav0");
  TrackerService tracker(lcm.get(), &publisher, TrackerAlone(), &TestVocabulary(), "");
  int acks = 0;
  std::mutex mutex;
  bus::Subscriber subscriber(lcm.get());
  subscriber.Subscribe<stitch::frame_ack_t>(bus::Channel("uav0", bus::kFrameAck),
                                            [&](std::unique_ptr<stitch::frame_ack_t>, const std::string&) {
                                              std::lock_guard<std::mutex> lock(mutex);
                                              ++acks;
                                            });
  bus::Dispatcher dispatcher(lcm.get());
  dispatcher.Start();
  tracker.Start();
  stitch::frame_t frame{};
  frame.camera = ToMessage(Camera::Pinhole(64, 48, 50, 50, 31.5, 23.5));
  EncodeImage(cv::Mat(48, 64, CV_8U, cv::Scalar(9)), ImageEncoding::kGray8, 90, &frame);
  PublishAs(&publisher, &frame, {0, 1, 1, 2, 1});  // a re-send of 1, then a late copy of 1
  std::this_thread::sleep_for(100ms);
  tracker.Stop();
  dispatcher.Stop();
  EXPECT_EQ(tracker.frames_tracked(), 3);
  std::lock_guard<std::mutex> lock(mutex);
  EXPECT_EQ(acks, 5);
}

// The security issue's row: one forged 0-byte FRAME numbered 2^31-1 in the ingest's session made
// the tracker acknowledge every later real frame as "already tracked" and record none of them. A
// frame far ahead of the session's newest is refused, and a frame of another size than the
// camera's is not decoded.
TEST(Tracker, AFrameFarAheadOfItsSessionOrOfAnotherSizeIsRefused) {
  auto lcm = bus::OpenLcm("memq://");
  bus::Publisher publisher(lcm.get(), "uav0");
  TrackerService tracker(lcm.get(), &publisher, TrackerAlone(), &TestVocabulary(), "");
  std::mutex mutex;
  std::set<int> acked;
  std::map<int, std::string> details;
  bus::Subscriber subscriber(lcm.get());
  subscriber.Subscribe<stitch::frame_ack_t>(bus::Channel("uav0", bus::kFrameAck),
                                            [&](std::unique_ptr<stitch::frame_ack_t> ack, const std::string&) {
                                              std::lock_guard<std::mutex> lock(mutex);
                                              acked.insert(ack->frame_index);
                                            });
  subscriber.Subscribe<stitch::tracking_status_t>(
      bus::Channel("uav0", bus::kTrackingStatus),
      [&](std::unique_ptr<stitch::tracking_status_t> status, const std::string&) {
        std::lock_guard<std::mutex> lock(mutex);
        details[status->frame_index] = status->detail;
      });
  bus::Dispatcher dispatcher(lcm.get());
  dispatcher.Start();
  tracker.Start();
  stitch::frame_t frame{};
  frame.camera = ToMessage(Camera::Pinhole(64, 48, 50, 50, 31.5, 23.5));
  EncodeImage(cv::Mat(48, 64, CV_8U, cv::Scalar(9)), ImageEncoding::kGray8, 90, &frame);
  stitch::frame_t forged = frame;
  forged.data.clear();
  forged.num_bytes = 0;
  stitch::frame_t wrong_size = frame;
  EncodeImage(cv::Mat(480, 640, CV_8U, cv::Scalar(9)), ImageEncoding::kGray8, 90, &wrong_size);
  PublishAs(&publisher, &frame, {0});
  PublishAs(&publisher, &forged, {std::numeric_limits<int32_t>::max()});
  PublishAs(&publisher, &wrong_size, {1});
  PublishAs(&publisher, &frame, {2, 3});
  std::this_thread::sleep_for(100ms);
  tracker.Stop();
  dispatcher.Stop();
  EXPECT_EQ(tracker.frames_tracked(), 4);  // 0, 2, 3 and 1, skipped
  std::lock_guard<std::mutex> lock(mutex);
  EXPECT_EQ(acked, (std::set<int>{0, 1, 2, 3}));  // never the forged one
  EXPECT_NE(details[1].find("a 640x480 frame for a 64x48 camera; not decoded"), std::string::npos) << details[1];
  EXPECT_EQ(details.count(std::numeric_limits<int32_t>::max()), 0u);
}

}  // namespace
}  // namespace stitch
