"""docs/templates.md's figures of the sensor model against the real Kinect frame are those of
docs/results/sensor_vs_real.json (today's parameters) and sensor_vs_real_before.json (the earlier ones);
tests/scripts/test_sensor_vs_real.py checks that the script measures them."""

from __future__ import annotations

from doc_figures import doc, missing, num, pct, result

DOC = "docs/templates.md"


def test_the_sensor_model_against_the_real_frame() -> None:
    now, before = result("sensor_vs_real.json"), result("sensor_vs_real_before.json")
    real, model, earlier = now["real"], now["synthetic_mean"], before["synthetic_mean"]
    moved = now["misregistration_px"]
    per_object = real["residual_per_object_median_mm"]
    sensor, sensor_before = now["sensor_model"], before["sensor_model"]
    assert now["seeds"] == before["seeds"] and len(now["objects"]) == 7 and moved["dy"] == 0

    def both(key: str, digits: int = 1) -> str:
        return f"{pct(real[key], digits)} / {pct(model[key], digits)}"

    assert not missing(
        doc(DOC),
        [
            f"passes it through the sensor model (mean of {now['seeds']} draws)",
            f"the visible table, {now['pixels_compared']['scene']:,} px): missing depth within 1 px of a depth edge "
            f"real {pct(real['missing_edge_0_1px'])} % / model {pct(model['missing_edge_0_1px'])} % (2–3 px: "
            f"{both('missing_edge_2_3px')} %), away from edges {both('missing_interior', 2)} %, on object pixels "
            f"{both('missing_objects', 2)} %",
            f"the model dropped {pct(earlier['missing_edge_0_1px'], 0)} % at edges and "
            f"{pct(earlier['missing_interior'])} % elsewhere ({pct(earlier['missing_objects'], 0)} % of object "
            f"pixels); `edge_dropout` ({sensor_before['edge_dropout']} → {sensor['edge_dropout']}) and "
            f"`random_dropout` ({sensor_before['random_dropout']} → {sensor['random_dropout']})",
            f"The real frame misses {pct(real['missing_frame'])} % of all its pixels",
            f"Noise after a plane fit in 8×8 tiles: real {num(real['noise_plane_std_mm'], 2)} mm, model "
            f"{num(model['noise_plane_std_mm'], 2)} mm; the real noise is spatially correlated (neighbours "
            f"{num(real['noise_neighbour_corr'], 2)}, model {num(model['noise_neighbour_corr'], 2).replace('-', '−')})"
            f", so it grows with the tile (4 px {num(real['noise_plane_std_4px_mm'], 2)}, 16 px "
            f"{num(real['noise_plane_std_16px_mm'], 2)} mm) while the model's white noise stays at "
            f"{num(model['noise_plane_std_16px_mm'])}",
            f"Disparity steps near {real['median_depth_mm']:,.0f} mm: {num(real['depth_step_mm'])} mm in both",
            f"median +{num(real['residual_objects_median_mm'])} mm, MAD {num(real['residual_objects_mad_mm'])} mm "
            f"(per object {num(min(per_object)).replace('-', '−')} mm for the half-hidden eggbox to "
            f"+{num(max(per_object))} mm); the real depth fits best moved {moved['dx']} px right (median "
            f"|residual| {num(moved['unmoved_mm'])} → {num(moved['median_abs_residual_mm'])} mm)",
            f"real outlines bleed {num(real['bleed_px'])} px into the background",
        ],
    )
    assert (
        model["depth_step_mm"] == real["depth_step_mm"] and model["bleed_px"] == 0
    )  # "in both"; the model not
