// make_prompt "A pair of polka-dotted sneakers" [--enriched "proposal from a text enricher"] [--json]
// Prints the source-video prompt of the paper's prompt protocol.
#include <iostream>
#include <nlohmann/json.hpp>
#include <string>

#include "orbitforge/pipeline/completion/prompt.hpp"

int main(int argc, char** argv) {
  std::string subject, proposal;
  bool json = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--enriched" && i + 1 < argc) {
      proposal = argv[++i];
    } else if (a == "--json") {
      json = true;
    } else if (a == "-h" || a == "--help") {
      std::cout << "usage: make_prompt TEXT [--enriched PROPOSAL] [--json]\n";
      return 0;
    } else if (subject.empty() && a.rfind("--", 0) != 0) {
      subject = a;
    } else {
      std::cerr << "make_prompt: unexpected argument '" << a << "'\n";
      return 2;
    }
  }
  if (subject.empty()) {
    std::cerr << "usage: make_prompt TEXT [--enriched PROPOSAL] [--json]\n";
    return 2;
  }
  const auto r = orbitforge::make_prompt(subject, proposal);
  if (json) {
    std::cout << nlohmann::json{{"original", r.original}, {"enriched", r.enriched},
                                {"video_prompt", r.video_prompt}, {"enrichment", r.enrichment}}
                     .dump(2)
              << "\n";
  } else {
    std::cout << r.video_prompt << "\n";
  }
  return 0;
}
