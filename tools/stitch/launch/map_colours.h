#pragma once
// The colours of a run's map from the flight's own images: each point takes the colour of its
// pixel in the first keyframe that sees it. The merger, on the ground, has no images; the
// launcher and `stitch export colmap` have the dataset the run played.

#include <string>

#include "stitch/io/colmap_model.h"

namespace stitch {

// The model (the merger's colmap/, images named agentA-frameNNNNNN) on the images of the dataset
// at `images` played from `start_frame`: each image named by its file relative to `images`, the
// model scaled to the images' size where the run worked at a reduced one, each point coloured
// from the first image that sees it. `scratch` is a file it may write and remove (the dataset's
// calibration). Throws stitch::Error naming what is missing: a model of several aircraft, a
// frame without an image file (a video), a frame the dataset does not hold.
// The frame of the flight a model image is (the merger names them agentA-frameNNNNNN, frames
// counted from where the run started). Throws stitch::Error for another name, or an image of
// another aircraft than the first (agent 0).
int FrameOfModelImage(const ColmapImage& image);

ColmapModel ModelOnImages(ColmapModel model, const std::string& images, int start_frame, const std::string& scratch);

// The model's points coloured from the keyframes' frames of the video at `video` played from
// `start_frame` (decoded in order, in colour; the features scaled to the video's size where the run
// worked at a reduced one). Throws stitch::Error: a model of several aircraft, a video that does
// not decode or ends before a keyframe's frame.
ColmapModel ColourFromVideo(ColmapModel model, const std::string& video, int start_frame);

// Recolours the PLY cloud at `ply_path` (WritePly's) from `coloured`: each point at a model
// point's position takes that point's colour; the others (seen by fewer than two of the model's
// images) grey. Returns how many points took an image's colour. Throws stitch::Error.
int ColourCloudFromModel(const std::string& ply_path, const ColmapModel& coloured, const std::string& frame);

}  // namespace stitch
