#include "services/common/convert.h"

#include <cmath>
#include <functional>
#include <limits>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "stitch/util/error.h"

namespace stitch {
namespace {

TEST(Convert, CameraRoundTrips) {
  const Camera camera = Camera::Pinhole(752, 480, 458.654, 457.296, 367.215, 248.375, -0.28, 0.07, 0.0002, 1.7e-5);
  const Camera back = FromMessage(ToMessage(camera));
  EXPECT_EQ(back.params(), camera.params());
  EXPECT_EQ(back.width(), 752);
  stitch::camera_t broken = ToMessage(camera);
  broken.params[0] = -1;
  EXPECT_THROW(FromMessage(broken), Error);
  broken = ToMessage(camera);
  broken.model = 9;
  EXPECT_THROW(FromMessage(broken), Error);
}

TEST(Convert, TransformsRoundTrip) {
  const Rigid3d r(Eigen::Quaterniond(Eigen::AngleAxisd(0.5, Eigen::Vector3d(1, 1, 0).normalized())),
                  Eigen::Vector3d(1, 2, 3));
  const Rigid3d r_back = FromMessage(ToMessage(r));
  EXPECT_NEAR(r_back.rotation.angularDistance(r.rotation), 0, 1e-12);
  EXPECT_EQ(r_back.translation, r.translation);
  const Sim3d s(3.0, r.rotation, r.translation);
  EXPECT_DOUBLE_EQ(FromMessage(ToMessage(s)).scale, 3.0);
  stitch::rigid3_t zero{};
  EXPECT_THROW(FromMessage(zero), Error);
}

// The security issue's row: a forged closed-submap state with NaN translations was accepted and
// keyframes_merged.tsv held -nan. Every pose of every message goes through these.
TEST(Convert, NonFiniteTranslationsAreRefused) {
  const Rigid3d r(Eigen::Quaterniond::Identity(), Eigen::Vector3d(1, 2, 3));
  for (double bad : {std::nan(""), std::numeric_limits<double>::infinity()}) {
    stitch::rigid3_t rigid = ToMessage(r);
    rigid.translation[1] = bad;
    EXPECT_THROW(FromMessage(rigid), Error);
    stitch::sim3_t sim = ToMessage(Sim3d(2.0, r.rotation, r.translation));
    sim.translation[2] = bad;
    EXPECT_THROW(FromMessage(sim), Error);
  }
}

TEST(Convert, ImagesRoundTripInBothEncodings) {
  cv::Mat image(48, 64, CV_8U);
  cv::randu(image, 0, 255);
  cv::GaussianBlur(image, image, cv::Size(5, 5), 1.5);
  stitch::frame_t frame{};
  EncodeImage(image, ImageEncoding::kGray8, 90, &frame);
  EXPECT_EQ(frame.num_bytes, 48 * 64);
  EXPECT_EQ(cv::norm(DecodeImage(frame), image, cv::NORM_INF), 0);
  EncodeImage(image, ImageEncoding::kJpeg, 95, &frame);
  EXPECT_LT(frame.num_bytes, 48 * 64);
  EXPECT_LT(cv::norm(DecodeImage(frame), image, cv::NORM_L1) / image.total(), 3.0);
}

TEST(Convert, MalformedFramesAreRejectedWithAReason) {
  cv::Mat image(48, 64, CV_8U, cv::Scalar(7));
  stitch::frame_t frame{};
  EncodeImage(image, ImageEncoding::kGray8, 90, &frame);
  frame.data.pop_back();
  frame.num_bytes--;
  try {
    DecodeImage(frame);
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("3071 bytes"), std::string::npos) << e.what();
  }
  EncodeImage(image, ImageEncoding::kJpeg, 90, &frame);
  frame.data.resize(20);
  frame.num_bytes = 20;
  EXPECT_THROW(DecodeImage(frame), Error);
  frame.encoding = 42;
  EXPECT_THROW(DecodeImage(frame), Error);
  frame.width = -3;
  EXPECT_THROW(DecodeImage(frame), Error);
}

// The security issue's row: a 332-byte JPEG claiming 32000x32000 grew the tracker by a gigabyte
// before it was refused. Its header is read first; the image is never decoded.
TEST(Convert, AJpegIsRefusedBeforeDecodingWhenItsHeaderClaimsAnotherSize) {
  cv::Mat image(48, 64, CV_8U, cv::Scalar(7));
  stitch::frame_t frame{};
  EncodeImage(image, ImageEncoding::kJpeg, 90, &frame);
  ASSERT_EQ(JpegSize(frame.data), std::make_pair(64, 48));
  for (size_t at = 2; at + 9 < frame.data.size(); ++at) {
    if (frame.data[at] == 0xFF && frame.data[at + 1] == 0xC0) {  // baseline frame header: 32000x32000
      frame.data[at + 5] = frame.data[at + 7] = 0x7D;
      frame.data[at + 6] = frame.data[at + 8] = 0x00;
    }
  }
  ASSERT_EQ(JpegSize(frame.data), std::make_pair(32000, 32000));
  try {
    DecodeImage(frame);
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("JPEG header says 32000x32000 but the frame says 64x48; not decoded"),
              std::string::npos)
        << e.what();
  }
  // No frame header at all (cut before it, or not a JPEG).
  EXPECT_EQ(JpegSize(std::vector<uint8_t>(frame.data.begin(), frame.data.begin() + 20)), std::nullopt);
  EXPECT_EQ(JpegSize(std::vector<uint8_t>(100, 0xFF)), std::nullopt);
  EXPECT_EQ(JpegSize({}), std::nullopt);
}

}  // namespace
}  // namespace stitch

namespace stitch {
namespace {

TEST(Convert, GnssFixesRoundTripAndImpossibleOnesAreRefused) {
  GnssFix fix;
  fix.t_ns = 123'456'789;
  fix.position = {48.1234567891, 11.5, 612.25};
  fix.horizontal_accuracy_m = 1.5;
  fix.vertical_accuracy_m = 2.5;
  fix.type = GnssFixType::kRtkFloat;
  const GnssFix back = FromMessage(ToMessage(fix));
  EXPECT_EQ(back.t_ns, fix.t_ns);
  EXPECT_EQ(back.position.latitude_deg, fix.position.latitude_deg);
  EXPECT_EQ(back.position.height_m, fix.position.height_m);
  EXPECT_EQ(back.vertical_accuracy_m, 2.5);
  EXPECT_EQ(back.type, GnssFixType::kRtkFloat);
  stitch::gnss_fix_t sized = ToMessage(fix);
  sized.header.agent = "uav0";
  EXPECT_EQ(sized.getEncodedSize(), 90);  // what docs/messages.md says it costs the link
  const std::vector<std::pair<std::function<void(stitch::gnss_fix_t*)>, std::string>> spoilt = {
      {[](stitch::gnss_fix_t* m) { m->fix_type = 6; }, "unknown fix type 6"},
      {[](stitch::gnss_fix_t* m) { m->fix_type = -1; }, "unknown fix type -1"},
      {[](stitch::gnss_fix_t* m) { m->t_ns = -1; }, "negative time"},
      {[](stitch::gnss_fix_t* m) { m->latitude_deg = NAN; }, "not a finite number"},
      {[](stitch::gnss_fix_t* m) { m->longitude_deg = 540; }, "longitude 540"},
      {[](stitch::gnss_fix_t* m) { m->horizontal_accuracy_m = 0; }, "accuracy"},
      {[](stitch::gnss_fix_t* m) { m->vertical_accuracy_m = INFINITY; }, "accuracy"},
  };
  for (const auto& [spoil, expected] : spoilt) {
    stitch::gnss_fix_t message = ToMessage(fix);
    spoil(&message);
    try {
      FromMessage(message);
      ADD_FAILURE() << "accepted, expected: " << expected;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace stitch
