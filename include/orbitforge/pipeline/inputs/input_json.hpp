#pragma once
// What the input contributed, for orbit.json and report.json: which frames of
// the source range were used, left out (and why) or withheld, and how many
// sparse points the source evidence kept.
#include <nlohmann/json.hpp>

#include "orbitforge/pipeline/inputs/recorded_input.hpp"

namespace orbitforge {

template <class Scalar>
nlohmann::json source_frames_json(const PipelineInput<Scalar>& in) {
  nlohmann::json used = nlohmann::json::array(), skipped = nlohmann::json::array(),
                 withheld = nlohmann::json::array();
  for (int f : in.source) (in.is_withheld(f) ? withheld : used).push_back(in.cameras[std::size_t(f)].name);
  for (const auto& s : in.source_skipped) skipped.push_back({{"name", s.name}, {"frame", s.frame + 1}, {"reason", s.reason}});
  return {{"range", {in.source_first + 1, in.source_last + 1}},
          {"frames_in_input", in.cameras.size()},
          {"trained", used},
          {"withheld", withheld},
          {"skipped", skipped}};
}

template <class Scalar>
nlohmann::json points_json(const PipelineInput<Scalar>& in) {
  const SourcePoints<Scalar> sp = source_points(in);
  return {{"total", sp.total}, {"kept", sp.kept}, {"dropped", sp.dropped}, {"rule", sp.rule},
          {"origin", in.points_origin}};
}

}  // namespace orbitforge
