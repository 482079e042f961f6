#pragma once
// report.md from report.json (the pipeline builds report.json; see pipeline.hpp
// for its keys). Plain Markdown tables a person can read next to the pictures.
#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>

namespace orbitforge {

namespace report_detail {
inline std::string num(const nlohmann::json& v, int digits = 2) {
  if (v.is_null()) return "-";
  if (v.is_boolean()) return v.get<bool>() ? "yes" : "no";
  if (v.is_number_integer()) return std::to_string(v.get<long long>());
  if (v.is_number()) {
    const double d = v.get<double>();
    if (!std::isfinite(d)) return d > 0 ? "inf" : "nan";
    char b[64];
    std::snprintf(b, sizeof(b), "%.*f", digits, d);
    return b;
  }
  if (v.is_string()) return v.get<std::string>();
  return v.dump();
}
inline const nlohmann::json& at(const nlohmann::json& j, const char* a, const char* b = nullptr,
                                const char* c = nullptr) {
  static const nlohmann::json null;
  const nlohmann::json* p = &j;
  for (const char* k : {a, b, c}) {
    if (!k) break;
    if (!p->is_object() || !p->contains(k)) return null;
    p = &(*p)[k];
  }
  return *p;
}
}  // namespace report_detail

inline std::string report_markdown(const nlohmann::json& r) {
  using report_detail::at;
  using report_detail::num;
  std::ostringstream md;
  md << "# OrbitForge pipeline report\n\n";
  md << "Input: " << num(at(r, "input")) << "  \n";
  md << "Completion provider: " << num(at(r, "completion_provider")) << "  \n";
  md << "Prompt: " << num(at(r, "prompt")) << "\n\n";
  md << "## Stage times (seconds)\n\n| stage | seconds |\n|---|---|\n";
  if (r.contains("stages"))
    for (auto it = r["stages"].begin(); it != r["stages"].end(); ++it)
      md << "| " << it.key() << " | " << num(it.value(), 1) << " |\n";
  md << "| total | " << num(at(r, "total_seconds"), 1) << " |\n\n";
  md << "## Coverage\n\nA = measured span of the views backed by evidence (degrees), M = monotone progress, "
        "closed = A > 330 and M > 0.9. R0: the source cameras; R1: the cameras of V_hat (R0's arc + completion). "
        "Both are rendered on the full canonical orbit (see \"rendered\" in report.json).\n\n"
        "| | A | M | closed |\n|---|---|---|---|\n";
  for (const char* k : {"R0", "R1"})
    md << "| " << k << " | " << num(at(r, "coverage", k, "A"), 1) << " | " << num(at(r, "coverage", k, "M"), 3)
       << " | " << num(at(r, "coverage", k, "closed")) << " |\n";
  md << "\n## Support-stratified quality\n\nBaked scenes rendered at the recorded cameras (R0: Gmed0; R1: "
        "final.ply; R1 paper-data: G1 trained on the paper's V_hat; bound: the oracle bound). Withheld = source "
        "frames no reconstruction trained on; gap = held-out recorded frames of the unsupported gap (never seen by "
        "any stage); training = the source frames the reconstructions trained on (a fit figure).\n\n"
        "| | withheld PSNR | SSIM | views | gap PSNR | SSIM | views | training PSNR | views |\n"
        "|---|---|---|---|---|---|---|---|---|\n";
  for (const char* k : {"R0", "R1", "R1_paper", "bound"}) {
    if (!at(r, "quality", k).is_object()) continue;
    if (at(r, "quality", k).contains("equals")) {
      md << "| " << k << " | = " << num(at(r, "quality", k, "equals")) << " (" << num(at(r, "quality", k, "why"))
         << ") | | | | | | | |\n";
      continue;
    }
    md << "| " << k;
    for (const char* s : {"supported_heldout", "gap_heldout", "supported_train"}) {
      const nlohmann::json& q = at(r, "quality", k, s);
      md << " | " << num(q.is_object() ? q["psnr"] : nlohmann::json());
      if (std::string(s) != "supported_train") md << " | " << num(q.is_object() ? q["ssim"] : nlohmann::json(), 3);
      md << " | " << num(q.is_object() ? q["views"] : nlohmann::json());
    }
    md << " |\n";
  }
  if (at(r, "quality", "R1", "gap_heldout_at_reference_lens").is_object())
    md << "\nGap views are scored at their recorded pose with the source cameras' lens, the camera G1 gives a "
          "completion frame; at the reference's own lens (the two estimates' focal lengths disagree): R0 "
       << num(at(at(r, "quality", "R0", "gap_heldout_at_reference_lens"), "psnr")) << " dB, R1 "
       << num(at(at(r, "quality", "R1", "gap_heldout_at_reference_lens"), "psnr")) << " dB.\n";
  if (at(r, "quality", "R1", "gap_heldout_view_fitted").is_object()) {
    md << "\nWith each scored view's camera turned and zoomed about its centre to fit its image (the scene fixed; "
          "this separates the scene's error from the scoring cameras' own):\n\n"
          "| | set | PSNR | SSIM | views | views fitted | turn mean / max (deg) | zoom change mean / max |\n"
          "|---|---|---|---|---|---|---|---|\n";
    for (const char* k : {"R0", "R1"})
      for (const char* s : {"gap_heldout_view_fitted", "supported_heldout_at_reference_view_fitted"}) {
        const nlohmann::json& q = at(r, "quality", k, s);
        if (!q.is_object()) continue;
        md << "| " << k << " | " << (std::string(s).rfind("gap", 0) == 0 ? "gap" : "withheld, reference cameras")
           << " | " << num(q["psnr"]) << " | " << num(q["ssim"], 3) << " | " << num(q["views"]) << " | "
           << num(at(q, "view_fit", "fitted_views")) << " | " << num(at(q, "view_fit", "turn_mean_deg"), 2) << " / "
           << num(at(q, "view_fit", "turn_max_deg"), 2) << " | " << num(at(q, "view_fit", "zoom_change_mean"), 4)
           << " / " << num(at(q, "view_fit", "zoom_change_max"), 4) << " |\n";
      }
  }
  md << "\nInput: " << num(at(r, "points", "kept")) << " of " << num(at(r, "points", "total"))
     << " sparse points kept (" << num(at(r, "points", "rule")) << "); background "
     << num(at(r, "background", "color")) << " (" << num(at(r, "background", "reason")) << ").\n";
  const auto& cams = at(r, "cameras");
  if (cams.is_object()) {
    md << "\n## Cameras\n\n" << num(at(cams, "path")) << ".";
    if (at(cams, "estimate").is_object())
      md << " Focal length " << num(at(cams, "estimate", "focal_px"), 1) << " px (" << num(at(cams, "estimate", "chosen_by"))
         << ").";
    const auto& refine = at(cams, "estimate", "orbit_refinement");
    if (refine.is_object()) {
      md << " Orbit refinement (" << num(at(refine, "mode")) << "): ";
      if (at(refine, "applied") == true)
        md << "applied, " << num(at(refine, "why")) << "; source arc " << num(at(refine, "arc_deg", "before"), 1)
           << " -> " << num(at(refine, "arc_deg", "after"), 1) << " deg, cameras moved up to "
           << num(at(refine, "max_rotation_change_deg"), 2) << " deg.";
      else
        md << "not applied, " << num(at(refine, "why")) << ".";
    }
    const auto& recal = at(cams, "recalibrated");
    if (recal.is_object()) {
      md << " G1's cameras, estimated again on the source and completion frames: ";
      if (at(recal, "applied") == true)
        md << "focal length " << num(at(recal, "focal_px", "first"), 1) << " -> "
           << num(at(recal, "focal_px", "recalibrated"), 1) << " px, " << num(at(recal, "registered", "completion"))
           << " of " << num(at(recal, "registered", "completion_frames")) << " completion frames registered.";
      else
        md << "not used, " << num(at(recal, "why_not")) << ".";
    }
    const auto& ref = at(cams, "reference");
    if (ref.is_object()) {
      md << "\n\nAgainst the reference model " << num(at(ref, "reference")) << " (aligned on "
         << num(at(ref, "alignment", "cameras")) << " source frames):\n\n| | estimated | reference |\n|---|---|---|\n"
         << "| source arc on the fitted orbit (deg) | " << num(at(ref, "source_arc_deg", "user"), 1) << " | "
         << num(at(ref, "source_arc_deg", "reference"), 1) << " |\n"
         << "| focal length at the working size (px) | " << num(at(ref, "focal_px", "user"), 1) << " | "
         << num(at(ref, "focal_px", "reference"), 1) << " |\n\n"
         << "- alignment residual: centres " << num(at(ref, "alignment", "centre_rms_relative"), 4)
         << " of their spread, rotations mean " << num(at(ref, "alignment", "rotation_mean_deg"), 2) << " / max "
         << num(at(ref, "alignment", "rotation_max_deg"), 2) << " deg\n"
         << "- frames outside the source against the fitted orbit's constant-speed motion: mean "
         << num(at(ref, "gap_azimuth_error_deg", "mean_abs"), 2) << " / max "
         << num(at(ref, "gap_azimuth_error_deg", "max_abs"), 2) << " deg over "
         << num(at(ref, "gap_azimuth_error_deg", "frames")) << " frames\n";
    }
    md << "\n";
  }
  md << "\n## Completion\n\n";
  md << "- loop-endpoint L1 of V_hat (0-255): " << num(at(r, "completion", "loop_endpoint_l1")) << "\n";
  md << "- anchor index error: mean " << num(at(r, "completion", "anchor_index_error", "mean")) << ", max "
     << num(at(r, "completion", "anchor_index_error", "max")) << " frames\n";
  const auto& tr = at(r, "completion", "temporal_trace");
  md << "- temporal trace: absolute turns " << num(at(tr, "absolute_turns"), 3) << ", net turns "
     << num(at(tr, "net_turns"), 3) << ", stall fraction " << num(at(tr, "stall_fraction"), 3) << ", reversals "
     << num(at(tr, "reversals")) << " (requested cameras)\n";
  const auto& ct = at(r, "completion", "completion_trace");
  if (ct.is_object())
    md << "- completion's own trace (frames matched to R0 renders): absolute turns "
       << num(at(ct, "absolute_turns"), 3) << ", net turns " << num(at(ct, "net_turns"), 3) << ", stall fraction "
       << num(at(ct, "stall_fraction"), 3) << ", reversals " << num(at(ct, "reversals")) << "\n";
  md << "\n";
  const auto& sp = at(r, "static_proxy", "variants");
  if (sp.is_object() && !sp.empty()) {
    md << "## Static proxy (G0 along the canonical orbit, " << num(at(r, "static_proxy", "views_scored"))
       << " views)\n\nAdjacent-frame L1 and its P95 over pairs, loop L1 across the orbit's start (0-255 scale; "
          "lower is steadier).\n\n| variant | adjacent L1 | L1 P95 | loop L1 |\n|---|---|---|---|\n";
    for (const char* v : {"frame_varying", "fixed_slice", "median"})
      md << "| " << v << " | " << num(at(sp, v, "adjacent_l1")) << " | " << num(at(sp, v, "adjacent_l1_p95"))
         << " | " << num(at(sp, v, "loop_l1")) << " |\n";
    md << "\n";
  }
  const auto& check = at(r, "orbit_check");
  if (check.is_object()) {
    if (at(check, "ok") == false) {
      md << "## Warning: the source cameras are not an orbit\n\n";
      for (const auto& w : at(check, "warnings")) md << "- " << num(w) << "\n";
      md << "\nFrames flagged: " << num(at(check, "flagged_frames")) << ". Everything after the orbit fit (support "
            "bins, completion request, G1's cameras) leans on it.\n\n";
    } else {
      md << "Orbit check: the source cameras fit a constant-speed orbit (speed trend " << num(at(check, "trend_halves"), 3)
         << ", circle RMSE " << num(at(check, "circle_rmse"), 4) << " of the radius).\n\n";
    }
  }
  md << "## Orbit fitting diagnostics\n\n| | |\n|---|---|\n";
  if (r.contains("diagnostics") && r["diagnostics"].is_object())
    for (auto it = r["diagnostics"].begin(); it != r["diagnostics"].end(); ++it)
      if (it.value().is_primitive()) md << "| " << it.key() << " | " << num(it.value(), 3) << " |\n";
  md << "\n## Pictures\n\n![contact sheet](contact_sheet.png)\n\n![support mask](support_mask.png) "
        "![top view](top_view.png)\n";
  return md.str();
}

}  // namespace orbitforge
