#pragma once
// A small command-line parser for stitch's tools and services:
//
//   ArgParser args("stitch-ingest", "Publishes camera frames on the bus.");
//   std::string dataset;
//   args.AddOption("--dataset", &dataset, "PATH", "dataset to play");
//   args.AddFlag("--synthetic", &synthetic, "play the synthetic flight");
//   if (!args.Parse(argc, argv)) return args.exit_code();   // --help or an error, printed
//
// Values may be given as "--name value" or "--name=value". Unknown options are errors.

#include <functional>
#include <string>
#include <vector>

namespace stitch {

class ArgParser {
 public:
  ArgParser(std::string program, std::string description);

  void AddOption(const std::string& name, std::string* value, const std::string& metavar, const std::string& help);
  void AddOption(const std::string& name, int* value, const std::string& metavar, const std::string& help);
  void AddOption(const std::string& name, double* value, const std::string& metavar, const std::string& help);
  // May be given several times; each value is appended.
  void AddOption(const std::string& name, std::vector<std::string>* values, const std::string& metavar,
                 const std::string& help);
  void AddFlag(const std::string& name, bool* value, const std::string& help);
  // Collects arguments that are not options (e.g. a run folder).
  void AddPositional(std::vector<std::string>* values, const std::string& metavar, const std::string& help,
                     int max_count = 1);
  void AddEpilog(const std::string& text) { epilog_ += text; }

  // Returns false when the program should exit: after --help (exit code 0) or on an error (the
  // message and usage are printed to stderr, exit code 2).
  bool Parse(int argc, char** argv);
  int exit_code() const { return exit_code_; }
  std::string Usage() const;
  // True if the option was given on the command line (not just defaulted).
  bool Given(const std::string& name) const;

 private:
  struct Option {
    std::string name, metavar, help, default_text;
    bool takes_value = true;
    std::function<bool(const std::string&)> set;  // false: value not valid
    bool given = false;
  };
  Option* Find(const std::string& name);

  std::string program_, description_, epilog_;
  std::vector<Option> options_;
  std::vector<std::string>* positional_ = nullptr;
  std::string positional_metavar_, positional_help_;
  int positional_max_ = 0;
  int exit_code_ = 0;
};

}  // namespace stitch
