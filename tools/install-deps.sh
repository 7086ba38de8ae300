#!/bin/sh
# Installs what stitch needs to build, test and run, from Debian 12 packages only.
# Run as root, or as a user with sudo.
set -eu
if [ "$(id -u)" -eq 0 ]; then SUDO=""; else SUDO="sudo"; fi
$SUDO apt-get update
$SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
  build-essential cmake pkg-config \
  liblcm-dev liblcm-bin libglib2.0-dev \
  libopencv-dev libavformat-dev libavcodec-dev libavutil-dev libswscale-dev libeigen3-dev libceres-dev \
  libyaml-cpp-dev nlohmann-json3-dev libsodium-dev libsqlite3-dev libgeographiclib-dev \
  libgtest-dev libgmock-dev libbenchmark-dev \
  gstreamer1.0-plugins-base gstreamer1.0-plugins-good gstreamer1.0-plugins-ugly gstreamer1.0-libav \
  default-jdk-headless liblcm-java libjchart2d-java lua5.2 liblcm-lua colmap \
  libboost-dev libjs-three \
  libgps-dev gpsd gpsd-clients python3-gps libexiv2-dev \
  gdal-bin libgdal-dev libproj-dev proj-data \
  iproute2 procps
