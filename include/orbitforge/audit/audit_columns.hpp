#pragma once
// The audit table's columns: where each figure sits in a run's report.json (a
// JSON pointer), its title and Markdown section, and the sections' order.
#include <string>
#include <vector>

namespace orbitforge {
namespace audit_detail {

// One column of the table.
struct Column {
  const char* key;      // JSON / CSV name
  const char* title;    // Markdown header
  const char* section;  // Markdown table it belongs to
  const char* pointer;  // JSON pointer into the report ("" for derived columns)
  int digits;           // Markdown decimals
  const char* alt = "";  // where older or other report layouts keep it (tried when `pointer` is missing)
};

inline const std::vector<Column>& columns() {
  static const std::vector<Column> c = {
      {"R0_A", "R0 A (deg)", "Coverage", "/coverage/R0/A", 1},
      {"R1_A", "R1 A (deg)", "Coverage", "/coverage/R1/A", 1},
      {"R1_M", "R1 M", "Coverage", "/coverage/R1/M", 3},
      {"R1_closed", "R1 closed", "Coverage", "/coverage/R1/closed", 0},
      {"lookat_error_deg", "look-at error (deg)", "Orbit diagnostics", "/diagnostics/lookat_error_deg", 3},
      {"radius", "radius", "Orbit diagnostics", "/orbit/radius", 4},
      {"plane_rms", "plane RMS (height std)", "Orbit diagnostics", "/diagnostics/height_std", 4},
      {"circle_rmse", "circle RMSE", "Orbit diagnostics", "/diagnostics/circle_rmse", 4},
      {"normal_rule", "normal rule", "Orbit diagnostics", "/diagnostics/normal_rule", 0},
      {"source_span_deg", "source span (deg)", "Orbit diagnostics", "/diagnostics/source_span_deg", 1},
      {"camera_path", "cameras", "Cameras", "/cameras/path", 0},
      {"orbit_check_ok", "orbit check passed", "Cameras", "/orbit_check/ok", 0},
      {"speed_trend", "speed trend (2nd / 1st half)", "Cameras", "/orbit_check/trend_halves", 3},
      {"arc_user", "source arc, estimated (deg)", "Cameras", "/cameras/reference/source_arc_deg/user", 1},
      {"arc_reference", "source arc, reference (deg)", "Cameras", "/cameras/reference/source_arc_deg/reference", 1},
      {"focal_user", "focal, estimated (px)", "Cameras", "/cameras/reference/focal_px/user", 1},
      {"focal_reference", "focal, reference (px)", "Cameras", "/cameras/reference/focal_px/reference", 1},
      {"reference_centre_residual", "alignment centre residual (of spread)", "Cameras",
       "/cameras/reference/alignment/centre_rms_relative", 4},
      {"reference_rotation_max", "alignment rotation residual max (deg)", "Cameras",
       "/cameras/reference/alignment/rotation_max_deg", 2},
      {"gap_azimuth_error_mean", "gap azimuth error mean (deg)", "Cameras",
       "/cameras/reference/gap_azimuth_error_deg/mean_abs", 2},
      {"gap_azimuth_error_max", "gap azimuth error max (deg)", "Cameras",
       "/cameras/reference/gap_azimuth_error_deg/max_abs", 2},
      {"R0_supported_psnr", "R0 sup PSNR (withheld)", "Quality", "/quality/R0/supported_heldout/psnr", 2},
      {"R1_supported_psnr", "R1 sup PSNR (withheld)", "Quality", "/quality/R1/supported_heldout/psnr", 2},
      {"R0_supported_ref_psnr", "R0 sup PSNR (withheld, at the reference's cameras)", "Quality",
       "/quality/R0/supported_heldout_at_reference/psnr", 2},
      {"R1_supported_ref_psnr", "R1 sup PSNR (withheld, at the reference's cameras)", "Quality",
       "/quality/R1/supported_heldout_at_reference/psnr", 2},
      {"R1_paper_supported_psnr", "R1 paper-data sup PSNR (withheld)", "Quality",
       "/quality/R1_paper/supported_heldout/psnr", 2},
      {"bound_supported_psnr", "bound sup PSNR (withheld)", "Quality", "/quality/bound/supported_heldout/psnr", 2},
      {"R0_gap_psnr", "R0 gap PSNR", "Quality", "/quality/R0/gap_heldout/psnr", 2},
      {"R1_gap_psnr", "R1 gap PSNR", "Quality", "/quality/R1/gap_heldout/psnr", 2},
      {"R1_paper_gap_psnr", "R1 paper-data gap PSNR", "Quality", "/quality/R1_paper/gap_heldout/psnr", 2},
      {"bound_gap_psnr", "bound gap PSNR", "Quality", "/quality/bound/gap_heldout/psnr", 2},
      {"gain_gap_psnr", "gain (R1 - R0 gap PSNR)", "Quality", "", 2},
      {"R0_gap_fitted_psnr", "R0 gap PSNR (view fitted)", "Quality, views fitted",
       "/quality/R0/gap_heldout_view_fitted/psnr", 2},
      {"R1_gap_fitted_psnr", "R1 gap PSNR (view fitted)", "Quality, views fitted",
       "/quality/R1/gap_heldout_view_fitted/psnr", 2},
      {"R1_supported_ref_fitted_psnr", "R1 sup PSNR (withheld, reference's cameras, view fitted)",
       "Quality, views fitted",
       "/quality/R1/supported_heldout_at_reference_view_fitted/psnr", 2},
      {"R1_gap_turn_mean", "R1 gap views' fitted turn, mean (deg)", "Quality, views fitted",
       "/quality/R1/gap_heldout_view_fitted/view_fit/turn_mean_deg", 2},
      {"R1_gap_zoom_mean", "R1 gap views' fitted zoom change, mean", "Quality, views fitted",
       "/quality/R1/gap_heldout_view_fitted/view_fit/zoom_change_mean", 4},
      {"R0_gap_ssim", "R0 gap SSIM", "Quality", "/quality/R0/gap_heldout/ssim", 3},
      {"R1_gap_ssim", "R1 gap SSIM", "Quality", "/quality/R1/gap_heldout/ssim", 3},
      {"R0_train_psnr", "R0 sup PSNR (training frames)", "Fit to training frames",
       "/quality/R0/supported_train/psnr", 2},
      {"R1_train_psnr", "R1 sup PSNR (training frames)", "Fit to training frames",
       "/quality/R1/supported_train/psnr", 2},
      {"R1_paper_train_psnr", "R1 paper-data sup PSNR (training frames)", "Fit to training frames",
       "/quality/R1_paper/supported_train/psnr", 2},
      {"bound_train_psnr", "bound sup PSNR (training frames)", "Fit to training frames",
       "/quality/bound/supported_train/psnr", 2},
      {"points_kept", "sparse points kept", "Input", "/points/kept", 0},
      {"points_dropped", "sparse points dropped", "Input", "/points/dropped", 0},
      {"background", "background", "Input", "/background/color", 0},
      {"loop_endpoint_l1", "loop-endpoint L1 (0-255)", "Completion", "/completion/loop_endpoint_l1", 2},
      {"anchor_error_mean", "anchor index error mean", "Completion", "/completion/anchor_index_error/mean", 2},
      {"anchor_error_max", "anchor index error max", "Completion", "/completion/anchor_index_error/max", 0},
      {"seconds_orbit", "orbit (s)", "Stage seconds", "/stages/orbit", 1},
      {"seconds_g0", "g0 (s)", "Stage seconds", "/stages/g0", 1},
      {"seconds_static_proxy", "static proxy (s)", "Stage seconds", "/stages/static_proxy", 1},
      {"seconds_completion", "completion (s)", "Stage seconds", "/stages/completion", 1},
      {"seconds_g1", "g1 (s)", "Stage seconds", "/stages/g1", 1},
      {"seconds_report", "report (s)", "Stage seconds", "/stages/report", 1},
      {"total_seconds", "total (s)", "Stage seconds", "/total_seconds", 1},
      {"seconds_g1_paper", "g1 paper-data (s, comparison)", "Stage seconds", "/comparison_seconds/g1_paper", 1},
      {"seconds_bound", "bound (s, comparison)", "Stage seconds", "/comparison_seconds/bound", 1},
      {"static_frame_varying_adjacent_l1", "frame-varying adj L1", "Static proxy",
       "/static_proxy/variants/frame_varying/adjacent_l1", 3, "/static_proxy/frame_varying/adjacent_l1"},
      {"static_frame_varying_adjacent_l1_p95", "frame-varying adj L1 P95", "Static proxy",
       "/static_proxy/variants/frame_varying/adjacent_l1_p95", 3, "/static_proxy/frame_varying/adjacent_l1_p95"},
      {"static_frame_varying_loop_l1", "frame-varying loop L1", "Static proxy",
       "/static_proxy/variants/frame_varying/loop_l1", 3, "/static_proxy/frame_varying/loop_l1"},
      {"static_fixed_slice_adjacent_l1", "fixed-slice adj L1", "Static proxy",
       "/static_proxy/variants/fixed_slice/adjacent_l1", 3, "/static_proxy/fixed_slice/adjacent_l1"},
      {"static_fixed_slice_adjacent_l1_p95", "fixed-slice adj L1 P95", "Static proxy",
       "/static_proxy/variants/fixed_slice/adjacent_l1_p95", 3, "/static_proxy/fixed_slice/adjacent_l1_p95"},
      {"static_fixed_slice_loop_l1", "fixed-slice loop L1", "Static proxy",
       "/static_proxy/variants/fixed_slice/loop_l1", 3, "/static_proxy/fixed_slice/loop_l1"},
      {"static_median_adjacent_l1", "median adj L1", "Static proxy",
       "/static_proxy/variants/median/adjacent_l1", 3, "/static_proxy/median/adjacent_l1"},
      {"static_median_adjacent_l1_p95", "median adj L1 P95", "Static proxy",
       "/static_proxy/variants/median/adjacent_l1_p95", 3, "/static_proxy/median/adjacent_l1_p95"},
      {"static_median_loop_l1", "median loop L1", "Static proxy",
       "/static_proxy/variants/median/loop_l1", 3, "/static_proxy/median/loop_l1"},
  };
  return c;
}

inline const std::vector<std::string>& sections() {
  static const std::vector<std::string> s = {"Coverage", "Orbit diagnostics", "Quality", "Quality, views fitted",
                                             "Fit to training frames",
                                             "Completion", "Input", "Stage seconds", "Static proxy"};
  return s;
}

}  // namespace audit_detail
}  // namespace orbitforge
