#pragma once
// Subcommands of the `stitch` launcher. Each returns the process exit code.

namespace stitch {

int RunCommand(int argc, char** argv);       // stitch run
int EvalCommand(int argc, char** argv);      // stitch eval
int RenderCommand(int argc, char** argv);    // stitch render
int ConfigCommand(int argc, char** argv);    // stitch config
int VocabCommand(int argc, char** argv);     // stitch vocab train|info
int BenchCommand(int argc, char** argv);     // stitch bench
int MapCommand(int argc, char** argv);       // stitch map
int RecordCommand(int argc, char** argv);    // stitch record
int CampaignCommand(int argc, char** argv);  // stitch campaign
int SpyCommand(int argc, char** argv);       // stitch spy
int ExportCommand(int argc, char** argv);    // stitch export colmap
int MosaicCommand(int argc, char** argv);    // stitch mosaic

}  // namespace stitch
