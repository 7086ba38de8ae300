#!/bin/sh
# Exits 0 when ThreadSanitizer programs run on this machine. GCC 12's TSan runtime refuses some
# kernels' address-space layouts ("unexpected memory mapping", high mmap randomization); CI then
# leaves the tsan build out and says so rather than failing on every test.
set -u
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
cat > "$dir/probe.cc" <<'PROBE'
#include <thread>
int main() { std::thread t([] {}); t.join(); return 0; }
PROBE
if ! g++ -fsanitize=thread -pthread "$dir/probe.cc" -o "$dir/probe" 2> "$dir/log"; then
  cat "$dir/log"; exit 1
fi
if ! "$dir/probe" > "$dir/log" 2>&1; then
  cat "$dir/log"; exit 1
fi
exit 0
