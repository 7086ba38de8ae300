# Small helpers shared by the project's CMakeLists.

# Where real datasets live when the project sits beside ../shared (benchmarks and real-data tests
# skip with a message when it is absent).
set(STITCH_DATASETS_DIR "${PROJECT_SOURCE_DIR}/../shared/datasets" CACHE PATH
    "Folder with the real benchmark sequences (optional)")

# stitch_add_library(name SOURCES ... DEPS ...): a static layer library rooted at src/.
function(stitch_add_library name)
  cmake_parse_arguments(ARG "" "" "SOURCES;PUBLIC_DEPS;PRIVATE_DEPS" ${ARGN})
  add_library(${name} STATIC ${ARG_SOURCES})
  target_include_directories(${name} PUBLIC ${PROJECT_SOURCE_DIR}/src)
  target_link_libraries(${name} PUBLIC ${ARG_PUBLIC_DEPS} PRIVATE ${ARG_PRIVATE_DEPS})
endfunction()

# stitch_add_test(name SOURCES ... LIBS ... [LABELS ...] [TIMEOUT s]): a GoogleTest executable in
# build/bin/tests, each TEST registered with ctest.
function(stitch_add_test name)
  if(NOT STITCH_BUILD_TESTS)
    return()
  endif()
  cmake_parse_arguments(ARG "" "TIMEOUT" "SOURCES;LIBS;LABELS" ${ARGN})
  if(NOT ARG_TIMEOUT)
    set(ARG_TIMEOUT 120)
  endif()
  # Sanitizer builds run slower: their timeouts scale (STITCH_TEST_TIMEOUT_SCALE, set with the sanitizer).
  if(STITCH_TEST_TIMEOUT_SCALE)
    math(EXPR ARG_TIMEOUT "${ARG_TIMEOUT} * ${STITCH_TEST_TIMEOUT_SCALE}")
  endif()
  add_executable(${name} ${ARG_SOURCES})
  target_link_libraries(${name} PRIVATE ${ARG_LIBS} stitch_testing GTest::gtest GTest::gtest_main)
  target_compile_definitions(${name} PRIVATE
    STITCH_BIN_DIR="${CMAKE_BINARY_DIR}/bin"
    STITCH_SOURCE_DIR="${PROJECT_SOURCE_DIR}"
    STITCH_DATASETS_DIR="${STITCH_DATASETS_DIR}")
  set_target_properties(${name} PROPERTIES RUNTIME_OUTPUT_DIRECTORY ${CMAKE_BINARY_DIR}/bin/tests UNITY_BUILD OFF)
  if(NOT ARG_LABELS)
    set(ARG_LABELS unit)
  endif()
  # STITCH_SANITIZER_ENVIRONMENT: the sanitizer's runtime options (a list of VAR=VALUE), in sanitizer builds.
  gtest_discover_tests(${name}
    DISCOVERY_TIMEOUT 60
    PROPERTIES TIMEOUT ${ARG_TIMEOUT} LABELS "${ARG_LABELS}" ENVIRONMENT "${STITCH_SANITIZER_ENVIRONMENT}")
endfunction()

# stitch_add_benchmark(name SOURCES ... LIBS ...): a Google Benchmark program in build/bin
# (run by hand or by `stitch bench`; timings never run as tests).
function(stitch_add_benchmark name)
  if(NOT STITCH_BUILD_BENCHMARKS)
    return()
  endif()
  cmake_parse_arguments(ARG "" "" "SOURCES;LIBS" ${ARGN})
  add_executable(${name} ${ARG_SOURCES})
  target_link_libraries(${name} PRIVATE ${ARG_LIBS} stitch_testing benchmark::benchmark)
  set_target_properties(${name} PROPERTIES UNITY_BUILD OFF)
  target_compile_definitions(${name} PRIVATE STITCH_DATASETS_DIR="${STITCH_DATASETS_DIR}" STITCH_SOURCE_DIR="${PROJECT_SOURCE_DIR}")
endfunction()
