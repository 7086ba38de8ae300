#pragma once
// The orthomosaic's settings (orthomosaic.h): its resolution, tiles, the ground surface the
// images are laid on, and which pixels of an image may be used.

#include <string>

namespace stitch {

struct MosaicOptions {
  // Ground sample distance, metres per mosaic pixel in a map placed on Earth (in the map's own
  // units otherwise); 0: the images' own, the median over them of their height above the ground
  // over their focal length.
  double gsd_m = 0.0;
  int tile_px = 256;  // mosaic tiles are this many pixels a side (what is redrawn when an image moves)
  // The ground surface is a height grid from the map's points: cells of this many GSD a side, each
  // the median height of its points (cells without points take their neighbours').
  double surface_cell_gsd = 32.0;
  int surface_min_points = 3;     // points a cell needs to give its own height
  double max_off_nadir_deg = 45;  // a ground point seen further than this from an image's nadir is not taken from it
  int image_border_px = 4;        // pixels along each image's edge that are not used
  int max_pixels = 400'000'000;   // a mosaic larger than this is refused (a map with a stray camera far away)
  // The merger keeps the largest map's mosaic during the flight from the pictures it receives
  // (live_mosaic.h), on Earth where the GNSS fixes place it (every map they place), and writes it
  // as mosaic_live.tif with its records.
  bool live = true;
  // With `live`: how often the pictures received are laid, seconds (what a picture waits, at
  // most, before its tiles go to the viewer).
  double interval_s = 1.0;
  // With `live`: the tiles drawn anew go to the viewer (PNG, on the ground's MOSAIC_TILE), which
  // shows the mosaic on its page.
  bool publish_tiles = true;
  // A map whose points' RMS distance from their plane exceeds this fraction of the cameras' median
  // height above it is not a ground seen from above (a room, a street's facades): it gets no live
  // mosaic, and `stitch mosaic` refuses it unless told --force (a handheld camera indoors, TUM
  // fr1/rpy: 0.34-8.5; the default flight 0.07). 0: no limit. (Named for the live mosaic, where
  // it came first; run folders keep the name in their config.yaml.)
  double live_max_relief = 0.25;
  // With `live`: the pictures a map places before its relief is judged and its mosaic starts. The
  // first few cameras, close together, can see a young room's desk as flat as a field (TUM
  // fr1/rpy at twice its rate; docs/mosaic.md).
  int live_min_pictures = 10;
  // With `live`: the live mosaic stops (once, with a warning; what it drew stays, and `stitch
  // mosaic RUN` still makes one from the records) when its CPU per picture laid exceeds this,
  // over at least 8 pictures: the flight comes first, and a map that is not a survey of the
  // ground (oblique views of a room) costs several times a survey's picture (docs/mosaic.md).
  // 0: no limit.
  double live_max_cpu_ms_per_picture = 100.0;

  template <class Visitor>
  void VisitFields(Visitor& v) {
    v("gsd_m", gsd_m,
      "ground sample distance, metres per mosaic pixel for a map placed on Earth (the map's units otherwise); 0: the "
      "images' own (their median height above the ground over their focal length)");
    v("tile_px", tile_px, "the mosaic's tiles are this many pixels a side: what is redrawn when an image moves");
    v("surface_cell_gsd", surface_cell_gsd,
      "the ground the images are laid on is a height grid from the map's points, cells this many GSD a side, each the "
      "median height of its points");
    v("surface_min_points", surface_min_points,
      "points a surface cell needs for a height of its own (the others take their neighbours')");
    v("max_off_nadir_deg", max_off_nadir_deg,
      "a ground point seen further than this from an image's nadir is not taken from that image");
    v("image_border_px", image_border_px, "pixels along each image's edge that are not used");
    v("max_pixels", max_pixels, "a mosaic of more pixels is refused (a map with a stray camera far away)");
    v("live", live,
      "the merger keeps the largest map's mosaic during the flight from the keyframe pictures it receives and writes "
      "it as mosaic_live.tif with its records (the map's own frame and units; where the GNSS fixes place the map, "
      "every map they place, in metres east and north of the first fix)");
    v("interval_s", interval_s,
      "with live: the pictures received are laid this often, seconds (at most what a picture waits before its tiles "
      "reach the viewer)");
    v("publish_tiles", publish_tiles,
      "with live: the tiles drawn anew go to the viewer's page (PNG, on the ground's MOSAIC_TILE)");
    v("live_max_relief", live_max_relief,
      "a map whose points' RMS distance from their plane exceeds this fraction of the cameras' median height above it "
      "is not a ground seen from above (a room, a street): no live mosaic, and stitch mosaic refuses it unless "
      "--force; 0: no limit");
    v("live_min_pictures", live_min_pictures,
      "with live: pictures the map must place before its relief is judged and its mosaic starts");
    v("live_max_cpu_ms_per_picture", live_max_cpu_ms_per_picture,
      "with live: the live mosaic stops (with a warning) once its CPU per picture laid exceeds this, over at least 8 "
      "pictures (a map that is not a survey of the ground, e.g. a handheld camera indoors); 0: no limit");
  }
  bool Check(std::string* why) const;
};

}  // namespace stitch
