#pragma once
// exiv2's header (photos' metadata), without the warnings of exiv2 0.27's std::auto_ptr
// declarations; code that uses Exiv2::Image::AutoPtr wraps itself in STITCH_EXIV2_BEGIN/END.

#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wdeprecated-declarations"
#include <exiv2/exiv2.hpp>
#pragma GCC diagnostic pop

#define STITCH_EXIV2_BEGIN \
  _Pragma("GCC diagnostic push") _Pragma("GCC diagnostic ignored \"-Wdeprecated-declarations\"")
#define STITCH_EXIV2_END _Pragma("GCC diagnostic pop")
