// Under AddressSanitizer, what LeakSanitizer leaves out in every stitch program and test (linked
// into each through stitch_util: src/stitch/util/CMakeLists.txt). A runtime option cannot carry it:
// ctest's test properties hold one sanitizer variable, and ASAN_OPTIONS' suppressions file takes
// no leak entries. Only third-party code belongs here, each entry with the evidence; a leak in
// stitch's own code is a bug to fix (docs/testing.md).

#if defined(__SANITIZE_ADDRESS__)
extern "C" const char* __lsan_default_suppressions() {
  // GStreamer (over GLib) keeps 16 kB it g_malloc'ed once a pipeline has run: an H.264 clip written
  // through x264enc and mp4mux (`stitch render --out flight.mp4` exited 1 on it), a PNG folder
  // played through multifilesrc (LivePipeline.*). The stack ends in g_malloc, inside libraries
  // that are not instrumented.
  return "leak:g_malloc\n";
}
#endif
