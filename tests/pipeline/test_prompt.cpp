#include <catch2/catch.hpp>

#include "orbitforge/pipeline/completion/prompt.hpp"

using namespace orbitforge;

TEST_CASE("category rule supplies a support surface", "[pipeline][prompt]") {
  CHECK(support_rule_for("A ceramic vase with blue glaze").category == "ceramics");
  CHECK(support_rule_for("a cool teddy bear").category == "toy");  // toy listed before animal
  CHECK(support_rule_for("A pair of polka-dotted sneakers").category == "outdoor_small");
  CHECK(support_rule_for("a silver ring with a ruby").category == "jewelry");
  CHECK(support_rule_for("an acoustic guitar").category == "instrument");
  CHECK(support_rule_for("a glowing orb of mystery").category == "generic");
  const auto e = enrich_by_category("A ceramic vase.");
  CHECK(e.find("A ceramic vase ") == 0);
  CHECK(e.find("tabletop") != std::string::npos);
}

TEST_CASE("enricher proposals are accepted only with subject and environment", "[pipeline][prompt]") {
  const std::string subject = "A pair of polka-dotted sneakers";
  CHECK(accept_enrichment(subject, "A pair of polka-dotted sneakers standing on rough concrete pavement"));
  CHECK_FALSE(accept_enrichment(subject, "A pair of polka-dotted sneakers, very nice"));       // no environment
  CHECK_FALSE(accept_enrichment(subject, "A pair of shoes standing on the ground"));          // subject lost
  const auto r = make_prompt(subject, "A pair of polka-dotted sneakers on a garden path");
  CHECK(r.enrichment == "enricher");
  const auto f = make_prompt(subject, "Sneakers.");
  CHECK(f.enrichment == "category:outdoor_small");
  CHECK(f.video_prompt.find(f.enriched) == 0);
  CHECK(f.video_prompt.find("360-degree") != std::string::npos);
  CHECK(f.original == subject);
}

TEST_CASE("prompts already carrying the protocol stay unchanged", "[pipeline][prompt]") {
  const auto once = make_prompt("a red car");
  const auto twice = make_prompt(once.video_prompt);
  CHECK(twice.enrichment == "unchanged");
  CHECK(twice.video_prompt == once.video_prompt);
  // Deterministic.
  CHECK(make_prompt("a red car").video_prompt == once.video_prompt);
}
