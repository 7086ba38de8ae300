#include "stitch/util/args.h"

#include <cstdio>
#include <sstream>

namespace stitch {

ArgParser::ArgParser(std::string program, std::string description)
    : program_(std::move(program)), description_(std::move(description)) {}

void ArgParser::AddOption(const std::string& name, std::string* value, const std::string& metavar,
                          const std::string& help) {
  options_.push_back({name, metavar, help, *value, true, [value](const std::string& v) {
                        *value = v;
                        return true;
                      }});
}

void ArgParser::AddOption(const std::string& name, std::vector<std::string>* values, const std::string& metavar,
                          const std::string& help) {
  options_.push_back({name, metavar, help + " (may be repeated)", "", true, [values](const std::string& v) {
                        values->push_back(v);
                        return true;
                      }});
}

void ArgParser::AddOption(const std::string& name, int* value, const std::string& metavar, const std::string& help) {
  options_.push_back({name, metavar, help, std::to_string(*value), true, [value](const std::string& v) {
                        try {
                          size_t used = 0;
                          const int parsed = std::stoi(v, &used);
                          if (used != v.size()) return false;
                          *value = parsed;
                          return true;
                        } catch (const std::exception&) {
                          return false;
                        }
                      }});
}

void ArgParser::AddOption(const std::string& name, double* value, const std::string& metavar, const std::string& help) {
  std::ostringstream shown;
  shown << *value;
  options_.push_back({name, metavar, help, shown.str(), true, [value](const std::string& v) {
                        try {
                          size_t used = 0;
                          const double parsed = std::stod(v, &used);
                          if (used != v.size()) return false;
                          *value = parsed;
                          return true;
                        } catch (const std::exception&) {
                          return false;
                        }
                      }});
}

void ArgParser::AddFlag(const std::string& name, bool* value, const std::string& help) {
  options_.push_back({name, "", help, "", false, [value](const std::string&) {
                        *value = true;
                        return true;
                      }});
}

void ArgParser::AddPositional(std::vector<std::string>* values, const std::string& metavar, const std::string& help,
                              int max_count) {
  positional_ = values;
  positional_metavar_ = metavar;
  positional_help_ = help;
  positional_max_ = max_count;
}

ArgParser::Option* ArgParser::Find(const std::string& name) {
  for (auto& option : options_) {
    if (option.name == name) return &option;
  }
  return nullptr;
}

bool ArgParser::Given(const std::string& name) const {
  for (const auto& option : options_) {
    if (option.name == name) return option.given;
  }
  return false;
}

std::string ArgParser::Usage() const {
  std::ostringstream out;
  out << "usage: " << program_ << " [options]";
  if (positional_) out << " " << positional_metavar_;
  out << "\n\n" << description_ << "\n\noptions:\n";
  const auto line = [&](const std::string& left, const std::string& help) {
    out << "  " << left;
    if (left.size() < 28)
      out << std::string(28 - left.size(), ' ');
    else
      out << "\n  " << std::string(28, ' ');
    out << help << "\n";
  };
  if (positional_) line(positional_metavar_, positional_help_);
  for (const auto& option : options_) {
    std::string help = option.help;
    if (option.takes_value && !option.default_text.empty()) help += " (default: " + option.default_text + ")";
    line(option.name + (option.takes_value ? " " + option.metavar : ""), help);
  }
  line("-h, --help", "show this help and exit");
  if (!epilog_.empty()) out << "\n" << epilog_ << "\n";
  return out.str();
}

bool ArgParser::Parse(int argc, char** argv) {
  const auto fail = [&](const std::string& message) {
    std::fprintf(stderr, "%s: %s\n(see %s --help)\n", program_.c_str(), message.c_str(), program_.c_str());
    exit_code_ = 2;
    return false;
  };
  for (int i = 1; i < argc; ++i) {
    std::string arg = argv[i];
    if (arg == "-h" || arg == "--help") {
      std::fputs(Usage().c_str(), stdout);
      exit_code_ = 0;
      return false;
    }
    if (arg.rfind("--", 0) == 0) {
      std::string value;
      bool has_inline_value = false;
      const auto equals = arg.find('=');
      if (equals != std::string::npos) {
        value = arg.substr(equals + 1);
        arg = arg.substr(0, equals);
        has_inline_value = true;
      }
      Option* option = Find(arg);
      if (!option) return fail("unknown option " + arg);
      if (option->takes_value && !has_inline_value) {
        if (i + 1 >= argc) return fail(arg + " needs a value (" + option->metavar + ")");
        value = argv[++i];
      } else if (!option->takes_value && has_inline_value) {
        return fail(arg + " takes no value");
      }
      if (!option->set(value)) return fail("'" + value + "' is not a valid " + option->metavar + " for " + arg);
      option->given = true;
      continue;
    }
    if (positional_ && static_cast<int>(positional_->size()) < positional_max_) {
      positional_->push_back(arg);
      continue;
    }
    return fail("unexpected argument '" + arg + "'");
  }
  return true;
}

}  // namespace stitch
