#pragma once
// Order statistics of a list of numbers.

#include <algorithm>
#include <vector>

namespace stitch {

// The upper median (the element at size / 2 once sorted); 0 for an empty list.
inline double Median(std::vector<double> values) {
  if (values.empty()) return 0;
  const auto middle = values.begin() + static_cast<std::ptrdiff_t>(values.size() / 2);
  std::nth_element(values.begin(), middle, values.end());
  return *middle;
}

}  // namespace stitch
