#pragma once
// Fields of the comma-separated files the geo module reads (gnss.csv, trajectory_wgs84.csv):
// each parsed whole or refused.

#include <cstdint>
#include <string>
#include <vector>

namespace stitch {

// Without leading and trailing blanks (spaces, tabs, a CR).
std::string Trimmed(const std::string& text);
// A whole field as a finite number; false for anything else ("1.5x", "", "nan").
bool ParseNumber(const std::string& field, double* value);
// A whole field as a non-negative integer within int64 (a time in nanoseconds); false otherwise.
bool ParseTime(const std::string& field, int64_t* value);
// The fields between commas (a line ending in a comma has an empty last field).
std::vector<std::string> SplitFields(const std::string& line);

}  // namespace stitch
