#pragma once
// Options structs list their fields once, and get YAML loading, dumping and help from that list:
//
//   struct Options {
//     int num_features = 1000;  // ORB features per frame
//     template <class Visitor> void VisitFields(Visitor& v) {
//       v("num_features", num_features, "ORB features per frame");
//     }
//     bool Check(std::string* why) const;
//   };
//
// Loading rejects unknown keys (a typo must not silently keep a default) and values of the wrong
// type; a missing key keeps the documented default. The resolved options are dumped to the run's
// folder and logged, so every run says exactly what it used. Nested options structs nest in YAML.

#include <set>
#include <string>
#include <type_traits>
#include <utility>

#include <yaml-cpp/yaml.h>

#include "stitch/util/error.h"

namespace stitch {

namespace options_internal {

struct NullVisitor {
  template <class Field>
  void operator()(const char*, Field&, const char* = "") {}
};

template <class T, class = void>
struct HasVisitFields : std::false_type {};
template <class T>
struct HasVisitFields<T, std::void_t<decltype(std::declval<T&>().VisitFields(std::declval<NullVisitor&>()))>>
    : std::true_type {};

template <class T, class = void>
struct HasCheck : std::false_type {};
template <class T>
struct HasCheck<T, std::void_t<decltype(std::declval<const T&>().Check(std::declval<std::string*>()))>>
    : std::true_type {};

}  // namespace options_internal

// Runs options.Check() where the struct has one; throws stitch::Error naming `context`.
template <class Options>
void CheckOptions(const Options& options, const std::string& context) {
  if constexpr (options_internal::HasCheck<Options>::value) {
    std::string why;
    if (!options.Check(&why)) throw Error(context + ": " + why);
  }
}

class OptionsReader {
 public:
  OptionsReader(const YAML::Node& node, std::string context) : node_(node), context_(std::move(context)) {
    if (node_ && !node_.IsNull() && !node_.IsMap()) {
      throw Error(context_ + ": expected a map of settings");
    }
  }

  template <class Field>
  void operator()(const char* name, Field& field, const char* /*help*/ = "") {
    known_.insert(name);
    if (!node_ || node_.IsNull()) return;
    const YAML::Node child = node_[name];
    if (!child) return;  // missing: keep the documented default
    Read(child, field, Path(name));
  }

  // Throws if the node holds keys no field claimed.
  void Finish() const {
    if (!node_ || node_.IsNull()) return;
    for (const auto& entry : node_) {
      const std::string key = entry.first.as<std::string>();
      if (!known_.count(key)) {
        std::string valid;
        for (const auto& k : known_) valid += (valid.empty() ? "" : ", ") + k;
        throw Error(Path(key.c_str()) + ": unknown setting (valid here: " + valid + ")");
      }
    }
  }

 private:
  std::string Path(const char* name) const { return context_.empty() ? std::string(name) : context_ + "." + name; }

  template <class Field>
  static void Read(const YAML::Node& node, Field& field, const std::string& where) {
    if constexpr (options_internal::HasVisitFields<Field>::value) {
      OptionsReader nested(node, where);
      field.VisitFields(nested);
      nested.Finish();
    } else {
      try {
        field = node.as<Field>();
      } catch (const YAML::Exception&) {
        YAML::Emitter shown;
        shown << node;
        throw Error(where + ": cannot read '" + std::string(shown.c_str()) + "' as " + TypeName<Field>());
      }
    }
  }

  template <class Field>
  static const char* TypeName() {
    if constexpr (std::is_same_v<Field, bool>) return "true/false";
    if constexpr (std::is_integral_v<Field>) return "an integer";
    if constexpr (std::is_floating_point_v<Field>) return "a number";
    if constexpr (std::is_same_v<Field, std::string>) return "a string";
    return "the expected type";
  }

  YAML::Node node_;
  std::string context_;
  std::set<std::string> known_;
};

class OptionsWriter {
 public:
  explicit OptionsWriter(YAML::Emitter& out) : out_(out) {}

  template <class Field>
  void operator()(const char* name, Field& field, const char* help = "") {
    out_ << YAML::Key << name << YAML::Value;
    if constexpr (options_internal::HasVisitFields<Field>::value) {
      if (help && *help) out_ << YAML::Comment(help);
      out_ << YAML::BeginMap;
      field.VisitFields(*this);
      out_ << YAML::EndMap;
    } else {
      if constexpr (std::is_same_v<Field, double> || std::is_same_v<Field, float>) {
        out_ << YAML::Precision(10);
      }
      out_ << field;
      if (help && *help) out_ << YAML::Comment(help);
    }
  }

 private:
  YAML::Emitter& out_;
};

// Reads an options struct from a YAML map (missing keys keep defaults, unknown keys throw), then
// checks it. `context` names the place for error messages, e.g. "run.yaml: tracker".
template <class Options>
Options ReadOptions(const YAML::Node& node, const std::string& context, Options options) {
  OptionsReader reader(node, context);
  options.VisitFields(reader);
  reader.Finish();
  CheckOptions(options, context);
  return options;
}
// ...over the defaults.
template <class Options>
Options ReadOptions(const YAML::Node& node, const std::string& context) {
  return ReadOptions(node, context, Options());
}

// The options as a YAML document with each field's help as a comment.
template <class Options>
std::string DumpOptions(Options options) {
  YAML::Emitter out;
  out << YAML::BeginMap;
  OptionsWriter writer(out);
  options.VisitFields(writer);
  out << YAML::EndMap;
  return std::string(out.c_str()) + "\n";
}

// Loads a YAML file, with a clear error for a missing file or a syntax error.
YAML::Node LoadYamlFile(const std::string& path);

}  // namespace stitch
