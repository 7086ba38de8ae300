# Run after lcm-gen (cmake -DHEADERS="a.hpp;b.hpp" -P harden_generated.cmake). LCM 1.3.1's
# generated C++ decode trusts two things a malformed message controls:
#  - a string's length: it rejects one longer than the buffer but not 0 or negative, and then
#    copies (size_t)(length - 1) bytes (a crash; found by tests/bus_fuzz_test);
#  - an array's count: it resizes the vector before reading the elements, so a count of 10^8 in
#    a 1 kB message allocates gigabytes before the decode fails.
# A count is malformed when its elements, at the fewest bytes each takes on the wire
# (stitch_lcm/decode_bounds.hpp), cannot fit in the bytes left: memory then stays within a few
# times the message's size. This adds both checks to each generated header, and fails the build
# if the generated code no longer looks as expected (a new lcm-gen: review the checks).
foreach(header ${HEADERS})
  file(READ ${header} code)
  set(original "${code}")
  string(REGEX REPLACE "if\\(__([A-Za-z0-9_]+)_len__ > maxlen - pos\\) return -1;"
         "if(__\\1_len__ < 1 || __\\1_len__ > maxlen - pos) return -1;" code "${code}")
  # A string inside an array (string names[n]) has its length in __elem_len.
  string(REPLACE "if(__elem_len > maxlen - pos) return -1;" "if(__elem_len < 1 || __elem_len > maxlen - pos) return -1;"
         code "${code}")
  string(REGEX REPLACE "this->([A-Za-z0-9_]+)\\.resize\\(this->([A-Za-z0-9_]+)\\);"
         "if(!stitch_lcm::CountFits<decltype(this->\\1)::value_type>(this->\\2, maxlen - pos)) { return -1; } this->\\1.resize(this->\\2);"
         code "${code}")
  string(REPLACE "#include <lcm/lcm_coretypes.h>" "#include <lcm/lcm_coretypes.h>\n#include \"stitch_lcm/decode_bounds.hpp\""
         code "${code}")
  string(FIND "${code}" ".assign(" has_string)
  string(REGEX MATCH "(_len__|__elem_len) < 1 \\|\\|" checked_string "${code}")
  string(REGEX MATCH "if\\(__[A-Za-z0-9_]+ > maxlen - pos\\) return -1;" unchecked_string "${code}")
  if(has_string GREATER -1 AND (NOT checked_string OR unchecked_string))
    message(FATAL_ERROR "${header}: lcm-gen's string decode changed; review lcmtypes/harden_generated.cmake")
  endif()
  string(REGEX MATCHALL "\\.resize\\(this->" resizes "${code}")
  string(REGEX MATCHALL "CountFits<" bounded "${code}")
  list(LENGTH resizes resize_count)
  list(LENGTH bounded bounded_count)
  if(NOT resize_count EQUAL bounded_count)
    message(FATAL_ERROR "${header}: lcm-gen's array decode changed; review lcmtypes/harden_generated.cmake")
  endif()
  if(NOT code STREQUAL original)
    file(WRITE ${header} "${code}")
  endif()
endforeach()
