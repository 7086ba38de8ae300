#include "stitch/io/calibration.h"

#include <fstream>

#include <gtest/gtest.h>

#include "stitch/testing/temp_dir.h"
#include "stitch/util/error.h"

namespace stitch {
namespace {

void Write(const std::string& path, const std::string& text) {
  std::ofstream(path) << text;
}

std::string ErrorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

TEST(Calibration, ReadsOrbSlam2Settings) {
  testing::TempDir dir;
  Write(dir / "tum.yaml",
        "%YAML:1.0\nCamera.type: \"PinHole\"\nCamera.fx: 517.3\nCamera.fy: 516.5\nCamera.cx: 318.6\n"
        "Camera.cy: 255.3\nCamera.k1: 0.26\nCamera.k2: -0.95\nCamera.p1: -0.005\nCamera.p2: 0.002\n"
        "Camera.k3: 1.16\nCamera.width: 640\nCamera.height: 480\nCamera.fps: 30.0\n");
  const Camera camera = LoadCalibration(dir / "tum.yaml");
  EXPECT_EQ(camera.width(), 640);
  EXPECT_DOUBLE_EQ(camera.fx(), 517.3);
  EXPECT_DOUBLE_EQ(camera.params()[8], 1.16);
}

TEST(Calibration, ReadsOrbSlam3SettingsAndTakesSizeFromImages) {
  testing::TempDir dir;
  Write(dir / "s3.yaml",
        "%YAML:1.0\nCamera.type: \"PinHole\"\nCamera1.fx: 458.6\nCamera1.fy: 457.3\n"
        "Camera1.cx: 367.2\nCamera1.cy: 248.4\nCamera1.k1: -0.28\nCamera1.k2: 0.07\n"
        "Camera1.p1: 0.0002\nCamera1.p2: 0.00002\n");
  EXPECT_THROW(LoadCalibration(dir / "s3.yaml"), Error);  // no size anywhere
  const Camera camera = LoadCalibration(dir / "s3.yaml", 752, 480);
  EXPECT_EQ(camera.width(), 752);
  EXPECT_DOUBLE_EQ(camera.cy(), 248.4);
}

// ORB-SLAM's own example settings, as they are (our copies of their keys in testdata/).
std::string Example(const std::string& name) {
  return std::string(STITCH_SOURCE_DIR) + "/src/stitch/io/testdata/" + name;
}

TEST(Calibration, ReadsOrbSlamExampleSettingsAsTheyAre) {
  // ORB-SLAM2's TUM1.yaml: `Viewer.PointSize:2`, which a YAML parser refuses; no image size.
  const Camera tum = LoadCalibration(Example("orbslam2_tum1.yaml"), 640, 480);
  EXPECT_DOUBLE_EQ(tum.fx(), 517.306408);
  EXPECT_DOUBLE_EQ(tum.params()[8], 1.163314);  // k3
  EXPECT_EQ(tum.width(), 640);
  const Camera kitti = LoadCalibration(Example("orbslam2_kitti00-02.yaml"), 1241, 376);
  EXPECT_DOUBLE_EQ(kitti.cx(), 607.1928);
  EXPECT_EQ(kitti.height(), 376);
  // ORB-SLAM3's versioned layout: Camera1. intrinsics, the size stated (and checked).
  const Camera euroc = LoadCalibration(Example("orbslam3_euroc_mono.yaml"));
  EXPECT_EQ(euroc.width(), 752);
  EXPECT_DOUBLE_EQ(euroc.params()[7], 1.76187114e-05);  // p2
  EXPECT_NE(ErrorOf([&] { LoadCalibration(Example("orbslam3_euroc_mono.yaml"), 640, 480); }).find("752x480"),
            std::string::npos);
}

// Another camera's settings on these images: ORB-SLAM2's KITTI file (cx 607) on a 640x480 camera
// is doubted; each file on its own camera is not.
TEST(Calibration, DoubtsAPrincipalPointFarFromTheImagesCentre) {
  EXPECT_EQ(CalibrationDoubts(LoadCalibration(Example("orbslam2_tum1.yaml"), 640, 480)), "");
  EXPECT_EQ(CalibrationDoubts(LoadCalibration(Example("orbslam2_kitti00-02.yaml"), 1241, 376)), "");
  EXPECT_EQ(CalibrationDoubts(LoadCalibration(Example("orbslam3_euroc_mono.yaml"))), "");
  const std::string doubt = CalibrationDoubts(LoadCalibration(Example("orbslam2_kitti00-02.yaml"), 640, 480));
  EXPECT_NE(doubt.find("principal point (607.2, 185.2)"), std::string::npos) << doubt;
  EXPECT_NE(doubt.find("640x480 image (320, 240)"), std::string::npos) << doubt;
}

TEST(Calibration, ReadsTheFeatureSettingsOfAnOrbSlamFile) {
  const auto kitti = ReadOrbExtractorSettings(Example("orbslam2_kitti00-02.yaml"));
  ASSERT_EQ(kitti.size(), 5u);
  EXPECT_EQ(kitti.at("nFeatures"), 2000);
  EXPECT_EQ(kitti.at("scaleFactor"), 1.2);
  EXPECT_EQ(kitti.at("nLevels"), 8);
  EXPECT_EQ(kitti.at("iniThFAST"), 20);
  EXPECT_EQ(kitti.at("minThFAST"), 7);
  testing::TempDir dir;
  // Written by hand: no `%YAML:1.0` header, `key:value`, only some of the keys.
  Write(dir / "mine.yaml",
        "Camera.fx:500\nCamera.fy: 500\nCamera.cx: 320\nCamera.cy: 240\nORBextractor.nFeatures:1500\n");
  const auto mine = ReadOrbExtractorSettings(dir / "mine.yaml");
  ASSERT_EQ(mine.size(), 1u);
  EXPECT_EQ(mine.at("nFeatures"), 1500);
  EXPECT_DOUBLE_EQ(LoadCalibration(dir / "mine.yaml", 640, 480).fx(), 500);
  // Other layouts state none; a value that is no number is an error naming it.
  Write(dir / "sensor.yaml", "intrinsics: [458, 457, 367, 248]\nresolution: [752, 480]\n");
  EXPECT_TRUE(ReadOrbExtractorSettings(dir / "sensor.yaml").empty());
  Write(dir / "bad.yaml", "Camera.fx: 500\nORBextractor.nLevels: eight\n");
  EXPECT_NE(ErrorOf([&] { ReadOrbExtractorSettings(dir / "bad.yaml"); }).find("ORBextractor.nLevels is not a number"),
            std::string::npos);
}

TEST(Calibration, ReadsEurocSensorYaml) {
  testing::TempDir dir;
  Write(dir / "sensor.yaml",
        "%YAML:1.0\nsensor_type: camera\nT_BS:\n  cols: 4\n  rows: 4\n  data: [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]\n"
        "rate_hz: 20\nresolution: [752, 480]\ncamera_model: pinhole\nintrinsics: [458.654, 457.296, 367.215, 248.375] "
        "#fu, fv, cu, cv\n"
        "distortion_model: radial-tangential\ndistortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, "
        "1.76187114e-05]\n");
  const Camera camera = LoadCalibration(dir / "sensor.yaml", 752, 480);
  EXPECT_DOUBLE_EQ(camera.fx(), 458.654);
  EXPECT_DOUBLE_EQ(camera.params()[4], -0.28340811);
  EXPECT_DOUBLE_EQ(camera.params()[8], 0.0);
}

TEST(Calibration, ReadsKittiCalib) {
  testing::TempDir dir;
  Write(dir / "calib.txt",
        "P0: 7.188560e+02 0 6.071928e+02 0 0 7.188560e+02 1.852157e+02 0 0 0 1 0\n"
        "P1: 7.188560e+02 0 6.071928e+02 -3.861448e+02 0 7.188560e+02 1.852157e+02 0 0 0 1 0\n");
  const Camera camera = LoadCalibration(dir / "calib.txt", 1241, 376);
  EXPECT_DOUBLE_EQ(camera.fx(), 718.856);
  EXPECT_DOUBLE_EQ(camera.cy(), 185.2157);
  EXPECT_FALSE(camera.HasDistortion());
}

TEST(Calibration, SizeMismatchSaysBothSizes) {
  testing::TempDir dir;
  Write(dir / "c.yaml",
        "Camera.fx: 500\nCamera.fy: 500\nCamera.cx: 320\nCamera.cy: 240\nCamera.width: 640\nCamera.height: 480\n");
  const std::string why = ErrorOf([&] { LoadCalibration(dir / "c.yaml", 752, 480); });
  EXPECT_NE(why.find("640x480"), std::string::npos) << why;
  EXPECT_NE(why.find("752x480"), std::string::npos) << why;
}

TEST(Calibration, BadFilesGiveClearErrors) {
  testing::TempDir dir;
  EXPECT_NE(ErrorOf([&] { LoadCalibration(dir / "missing.yaml"); }).find("not found"), std::string::npos);
  Write(dir / "broken.yaml", "Camera.fx: [1, 2\n  : : :\n");
  EXPECT_NE(ErrorOf([&] { LoadCalibration(dir / "broken.yaml"); }).find("not valid YAML"), std::string::npos);
  Write(dir / "other.yaml", "hello: world\n");
  EXPECT_NE(ErrorOf([&] { LoadCalibration(dir / "other.yaml", 640, 480); }).find("not a calibration file"),
            std::string::npos);
  Write(dir / "nan.yaml", "Camera.fx: abc\nCamera.fy: 1\nCamera.cx: 1\nCamera.cy: 1\n");
  EXPECT_NE(ErrorOf([&] { LoadCalibration(dir / "nan.yaml", 640, 480); }).find("Camera.fx is not a number"),
            std::string::npos);
  Write(dir / "neg.yaml", "Camera.fx: -5\nCamera.fy: 1\nCamera.cx: 1\nCamera.cy: 1\n");
  EXPECT_NE(ErrorOf([&] { LoadCalibration(dir / "neg.yaml", 640, 480); }).find("must be positive"), std::string::npos);
}

TEST(Calibration, SaveThenLoadRoundTrips) {
  testing::TempDir dir;
  const Camera camera =
      Camera::Pinhole(752, 480, 458.654, 457.296, 367.215, 248.375, -0.28, 0.07, 0.0002, 1.7e-05, 0.001);
  SaveCalibration(camera, dir / "out.yaml");
  const Camera back = LoadCalibration(dir / "out.yaml");
  EXPECT_EQ(back.params(), camera.params());
  EXPECT_EQ(back.width(), 752);
  EXPECT_FALSE(ReadLineDelayUs(dir / "out.yaml")) << "a global shutter states none";
}

// A rolling shutter's readout delay per row rides along in the calibration (stitch's own key).
TEST(Calibration, ARollingShuttersLineDelayIsWrittenAndReadBack) {
  testing::TempDir dir;
  SaveCalibration(Camera::Pinhole(640, 480, 450, 450, 319.5, 239.5), dir / "rolling.yaml", 40);
  ASSERT_TRUE(ReadLineDelayUs(dir / "rolling.yaml"));
  EXPECT_DOUBLE_EQ(*ReadLineDelayUs(dir / "rolling.yaml"), 40);
  EXPECT_EQ(LoadCalibration(dir / "rolling.yaml").width(), 640);
}

}  // namespace
}  // namespace stitch
