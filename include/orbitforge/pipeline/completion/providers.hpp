#pragma once
// The completion providers by name (full_pipeline --completion NAME).
#include <memory>
#include <string>

#include "orbitforge/core/error.hpp"
#include "orbitforge/pipeline/completion/perturbed.hpp"
#include "orbitforge/pipeline/completion/provider.hpp"

namespace orbitforge {

inline const char* completion_provider_names() { return "external, oracle, perturbed, perturbed-geometric or none"; }

template <class Scalar>
std::unique_ptr<CompletionProvider<Scalar>> make_completion_provider(const std::string& name,
                                                                     const PerturbParams& perturb = {}) {
  if (name == "none") return std::make_unique<NoCompletion<Scalar>>();
  if (name == "oracle") return std::make_unique<OracleCompletion<Scalar>>();
  if (name == "perturbed") return std::make_unique<PerturbedOracleCompletion<Scalar>>(perturb);
  if (name == "perturbed-geometric") {  // and each frame's camera 1-2 degrees off the view it shows
    PerturbParams p = perturb;
    if (!(p.camera_error_deg > 0)) p.camera_error_deg = 1;
    return std::make_unique<PerturbedOracleCompletion<Scalar>>(p, name);
  }
  if (name == "external") return std::make_unique<ExternalCompletion<Scalar>>();
  fail("unknown completion provider '", name, "' (use ", completion_provider_names(), ")");
}

}  // namespace orbitforge
