// make_prompt "A pair of polka-dotted sneakers" [--enriched "proposal from a text enricher"] [--json]
// Prints the source-video prompt of the paper's prompt protocol.
#include <iostream>
#include <nlohmann/json.hpp>
#include <string>

#include "cli.hpp"
#include "orbitforge/pipeline/completion/prompt.hpp"

int main(int argc, char** argv) {
  using namespace orbitforge;
  return cli::run([&] {
    std::string subject, proposal;
    bool json = false;
    CLI::App app("make_prompt: the source-video prompt of the paper's prompt protocol.", "make_prompt");
    cli::setup(app);
    app.add_option("TEXT", subject, "the subject, e.g. \"A pair of polka-dotted sneakers\"")->required();
    app.add_option("--enriched", proposal, "a text enricher's proposal");
    app.add_flag("--json", json, "print the original, enriched and video prompts and the enrichment as JSON");
    cli::parse(app, argc, argv);
    const auto r = make_prompt(subject, proposal);
    if (json) {
      std::cout << nlohmann::json{{"original", r.original}, {"enriched", r.enriched},
                                  {"video_prompt", r.video_prompt}, {"enrichment", r.enrichment}}
                       .dump(2)
                << "\n";
    } else {
      std::cout << r.video_prompt << "\n";
    }
    return 0;
  });
}
