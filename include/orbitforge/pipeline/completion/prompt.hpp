#pragma once
// The source-video prompt protocol (paper, appendix "Prompt Protocol for
// Text-to-Video Source Generation"): a short benchmark prompt is kept as the
// semantic target and turned into a video-model instruction in two stages:
//   1. scene enrichment: an optional text enricher proposes a subject-with-support
//      sentence; it is accepted only if it keeps the subject's words and names a
//      concrete environment term. Otherwise a deterministic object-category rule
//      supplies the support surface.
//   2. the orbit-camera and rigidity wrapper.
// Prompts that already carry the full camera and rigidity protocol are left as they are.
#include <algorithm>
#include <cctype>
#include <string>
#include <vector>

namespace orbitforge {

namespace prompt_detail {

inline std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return s;
}

inline std::vector<std::string> words(const std::string& text) {
  std::vector<std::string> out;
  std::string w;
  for (char ch : lower(text)) {
    if (std::isalnum(static_cast<unsigned char>(ch)) || ch == '-') {
      w += ch;
    } else if (!w.empty()) {
      out.push_back(w);
      w.clear();
    }
  }
  if (!w.empty()) out.push_back(w);
  return out;
}

inline bool has_word(const std::vector<std::string>& ws, const std::string& key) {
  // Matches the key or its plural ("vase" matches "vases").
  for (const auto& w : ws)
    if (w == key || w == key + "s" || w == key + "es") return true;
  return false;
}

inline std::string trim_sentence(std::string s) {
  while (!s.empty() && (std::isspace(static_cast<unsigned char>(s.back())) || s.back() == '.')) s.pop_back();
  std::size_t b = 0;
  while (b < s.size() && std::isspace(static_cast<unsigned char>(s[b]))) ++b;
  return s.substr(b);
}

}  // namespace prompt_detail

// One row of the deterministic category rule.
struct SupportRule {
  std::string category;
  std::vector<std::string> keywords;
  std::string support;  // completes "<subject> <support>"
};

// The fixed rule table. Order matters: the first category with a matching
// keyword wins, so specific categories come before general ones.
inline const std::vector<SupportRule>& support_rules() {
  static const std::vector<SupportRule> rules = {
      {"jewelry", {"ring", "necklace", "bracelet", "earring", "jewel", "jewelry", "pendant", "brooch", "gem", "watch"},
       "resting on a dark velvet display pad, with soft static lighting"},
      {"instrument", {"guitar", "violin", "piano", "drum", "trumpet", "saxophone", "cello", "flute", "harp", "banjo"},
       "standing on a matte stage floor, with even static lighting"},
      {"ceramics", {"vase", "mug", "cup", "teapot", "bowl", "plate", "jar", "pot", "pitcher", "teacup"},
       "standing on a wooden tabletop, with its base flat on the table and soft static lighting"},
      {"toy", {"toy", "teddy", "doll", "lego", "robot", "plush", "puppet", "figurine", "action-figure", "block"},
       "standing on a wooden surface, with its base flat on the wood and soft static lighting"},
      {"food", {"cake", "bread", "pizza", "burger", "sandwich", "pancake", "donut", "fruit", "apple", "banana",
                "sushi", "cookie", "pie", "croissant"},
       "on a ceramic plate on a wooden kitchen table, with soft static lighting"},
      {"plant", {"flower", "sunflower", "plant", "cactus", "tree", "bonsai", "succulent", "rose", "tulip"},
       "planted in garden soil, with the stem firmly in the ground and static daylight"},
      {"animal", {"dog", "cat", "corgi", "rabbit", "bird", "horse", "fox", "owl", "frog", "squirrel", "bear", "lion",
                  "panda", "duck"},
       "sitting still on a grassy ground, with its feet on the ground and static daylight"},
      {"vehicle", {"car", "truck", "bus", "bicycle", "motorcycle", "tractor", "van", "scooter", "train", "tank"},
       "parked on a rough asphalt street, with all wheels on the ground and static daylight"},
      {"furniture", {"chair", "table", "sofa", "bench", "stool", "lamp", "desk", "bed", "cabinet"},
       "standing on a wooden floor in a plain room, with static lighting"},
      {"outdoor_small", {"shoe", "sneaker", "boot", "ball", "bucket", "hydrant", "mailbox", "stone", "rock",
                         "statue", "sculpture", "bottle", "can"},
       "standing on rough concrete pavement, with its base flat on the ground and static daylight"},
  };
  return rules;
}

// The rule used when no category matches.
inline const SupportRule& default_support_rule() {
  static const SupportRule rule{"generic", {}, "standing on a plain stone surface, with its base flat on the ground "
                                               "and static lighting"};
  return rule;
}

// Words that count as a concrete environment term in an enricher's proposal.
inline const std::vector<std::string>& environment_terms() {
  static const std::vector<std::string> terms = {"ground", "floor", "surface", "pavement", "garden",
                                                 "stone",  "table", "tabletop", "soil",    "street",
                                                 "grass",  "road",  "desk",     "wood",    "wooden",
                                                 "concrete", "sand", "pad", "stage", "shelf"};
  return terms;
}

inline const SupportRule& support_rule_for(const std::string& subject) {
  const auto ws = prompt_detail::words(subject);
  for (const auto& rule : support_rules())
    for (const auto& k : rule.keywords)
      if (prompt_detail::has_word(ws, k)) return rule;
  return default_support_rule();
}

// Stage 1 fallback: the subject placed on its category's support surface.
inline std::string enrich_by_category(const std::string& subject) {
  return prompt_detail::trim_sentence(subject) + " " + support_rule_for(subject).support + ".";
}

// Whether an enricher's proposal may be used: it must keep every content word of
// the subject (words of 3+ letters) and name at least one environment term.
inline bool accept_enrichment(const std::string& subject, const std::string& proposal) {
  const auto pw = prompt_detail::words(proposal);
  for (const auto& w : prompt_detail::words(subject)) {
    if (w.size() < 3 || w == "the" || w == "and" || w == "with") continue;
    if (!prompt_detail::has_word(pw, w)) return false;
  }
  for (const auto& t : environment_terms())
    if (prompt_detail::has_word(pw, t)) return true;
  return false;
}

// The camera and rigidity clauses of stage 2.
inline std::string orbit_camera_wrapper() {
  return "The camera performs a single continuous, constant-radius 360-degree side orbit around the subject "
         "with a fixed long lens: no zoom, no dolly, no speed variation, low-to-medium viewing height and "
         "constant elevation, with stable side-facing framing. The subject is rigid and stays locked to its "
         "support surface: no rolling, sliding, vibration, topology change, deformation, texture repainting or "
         "view-dependent reinterpretation. Static lighting, stable ground.";
}

// A prompt already written with the protocol (it asks for a 360-degree orbit and a
// rigid subject) is left unchanged.
inline bool has_orbit_protocol(const std::string& prompt) {
  const auto l = prompt_detail::lower(prompt);
  return l.find("360") != std::string::npos && l.find("orbit") != std::string::npos &&
         l.find("rigid") != std::string::npos;
}

struct PromptResult {
  std::string original;     // the semantic target, unchanged
  std::string enriched;     // subject with support surface
  std::string video_prompt; // what the text-to-video model receives
  std::string enrichment;   // "enricher", "category:<name>" or "unchanged"
};

// `enricher_proposal` is the text an optional enricher returned (empty if none ran).
inline PromptResult make_prompt(const std::string& original, const std::string& enricher_proposal = "") {
  PromptResult r;
  r.original = original;
  if (has_orbit_protocol(original)) {
    r.enriched = original;
    r.video_prompt = original;
    r.enrichment = "unchanged";
    return r;
  }
  if (!enricher_proposal.empty() && accept_enrichment(original, enricher_proposal)) {
    r.enriched = prompt_detail::trim_sentence(enricher_proposal) + ".";
    r.enrichment = "enricher";
  } else {
    r.enriched = enrich_by_category(original);
    r.enrichment = "category:" + support_rule_for(original).category;
  }
  r.video_prompt = r.enriched + " " + orbit_camera_wrapper();
  return r;
}

}  // namespace orbitforge
