#include "stitch/util/args.h"

#include <gtest/gtest.h>

namespace stitch {
namespace {

struct Argv {
  explicit Argv(std::vector<std::string> args) : storage(std::move(args)) {
    for (auto& s : storage) pointers.push_back(s.data());
  }
  int argc() { return static_cast<int>(pointers.size()); }
  char** argv() { return pointers.data(); }
  std::vector<std::string> storage;
  std::vector<char*> pointers;
};

TEST(ArgParser, ReadsOptionsFlagsAndPositionals) {
  std::string name = "default";
  int count = 1;
  double ratio = 0.5;
  bool verbose = false;
  std::vector<std::string> rest;
  ArgParser args("prog", "test");
  args.AddOption("--name", &name, "NAME", "a name");
  args.AddOption("--count", &count, "N", "a count");
  args.AddOption("--ratio", &ratio, "R", "a ratio");
  args.AddFlag("--verbose", &verbose, "talk");
  args.AddPositional(&rest, "DIR", "a folder");
  Argv a({"prog", "--name", "x", "--count=7", "run1", "--verbose", "--ratio", "0.25"});
  ASSERT_TRUE(args.Parse(a.argc(), a.argv()));
  EXPECT_EQ(name, "x");
  EXPECT_EQ(count, 7);
  EXPECT_DOUBLE_EQ(ratio, 0.25);
  EXPECT_TRUE(verbose);
  EXPECT_EQ(rest, std::vector<std::string>{"run1"});
  EXPECT_TRUE(args.Given("--count"));
}

TEST(ArgParser, ARepeatableOptionKeepsEveryValueInOrder) {
  ArgParser args("prog", "test");
  std::vector<std::string> settings;
  args.AddOption("--set", &settings, "K=V", "a setting");
  Argv a({"prog", "--set", "a=1", "--set=b=2,3", "--set", "c="});
  ASSERT_TRUE(args.Parse(a.argc(), a.argv()));
  EXPECT_EQ(settings, (std::vector<std::string>{"a=1", "b=2,3", "c="}));
  EXPECT_TRUE(args.Given("--set"));
}

TEST(ArgParser, RejectsUnknownOptionsAndBadValues) {
  int count = 1;
  ArgParser args("prog", "test");
  args.AddOption("--count", &count, "N", "a count");
  Argv unknown({"prog", "--cuont", "3"});
  EXPECT_FALSE(args.Parse(unknown.argc(), unknown.argv()));
  EXPECT_EQ(args.exit_code(), 2);
  Argv bad({"prog", "--count", "3x"});
  EXPECT_FALSE(args.Parse(bad.argc(), bad.argv()));
  Argv missing({"prog", "--count"});
  EXPECT_FALSE(args.Parse(missing.argc(), missing.argv()));
}

TEST(ArgParser, HelpExitsCleanlyAndListsOptions) {
  int count = 1;
  ArgParser args("prog", "does things");
  args.AddOption("--count", &count, "N", "a count");
  EXPECT_NE(args.Usage().find("--count N"), std::string::npos);
  EXPECT_NE(args.Usage().find("(default: 1)"), std::string::npos);
  Argv help({"prog", "--help"});
  testing::internal::CaptureStdout();
  EXPECT_FALSE(args.Parse(help.argc(), help.argv()));
  testing::internal::GetCapturedStdout();
  EXPECT_EQ(args.exit_code(), 0);
}

}  // namespace
}  // namespace stitch
