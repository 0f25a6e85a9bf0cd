"""`splatam info --input PATH [--format NAME] [--config NAME] [--steps] [--estimate-registration]
[--json]`: what a capture holds, whether its poses, depth units and intrinsics look consistent (the
reprojection check of docs/formats.md; with --steps at every step of the reference poses), how well
its colour and depth line up (edge agreement; with --estimate-registration the colour camera that
lines them up best), and which settings layers a run on it would use (budget + format layer)."""

from __future__ import annotations

import argparse
import json

from splat_core.config import describe_default_presets


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--input", required=True, help="capture folder or Record3D .r3d file")
    p.add_argument("--format", default=None, help="reader to use instead of detecting (tum, replica, scannet, "
                                                  "scannetpp, nerfcapture, record3d, strayscanner)")
    p.add_argument("--config", default=None, help="budget a run would use (default: as splatam run's, "
                   f"{describe_default_presets()})")
    p.add_argument("--resolution", default=None, metavar="WxH|L|native", help="as on splatam run")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    p.add_argument("--gap", type=int, default=10, help="frames between the two views of the pose check (10)")
    p.add_argument("--steps", action="store_true",
                   help="also check every step of the reference poses against the depth (reads every frame): "
                        "lists steps the images contradict, which an ATE against that reference charges to any method")
    p.add_argument("--estimate-registration", action="store_true",
                   help="search the colour camera's focal length and offset (tx, ty) that best line colour edges up "
                        "with depth edges over ~10 frames, and print the camera-file lines to add")


def settings(source, config) -> dict:
    """The settings layers a run of `config` on `source` uses, and its working size."""
    from splat_core.config import describe_layers, format_layer_settings
    from splat_core.run.resolution import describe_resolution, source_working_size

    return {"budget": config.name, "format_layer": config.format_layer,
            "format_settings": format_layer_settings(config.format_layer), "summary": describe_layers(config),
            "resolution": describe_resolution(config.resolution), "working_size": list(source_working_size(source, config)),
            "tracking_iterations": config.tracking.iterations, "mapping_iterations": config.mapping.iterations}


def registration(source, estimate: bool) -> dict:
    """Edge agreement of the frames as yielded, and with `estimate` the colour camera found."""
    from splat_core.registration_estimate import edge_agreement, estimate_registration, registered_by_writer

    out = {"edge_agreement": edge_agreement(source), "registered_by_reader": source.registered,
           "registered_by": registered_by_writer(source),
           "two_cameras": getattr(source, "two_cameras", None) is not None}
    if estimate and out["registered_by"]:
        out["estimate"] = {"already_registered": True, "not_estimated": out["registered_by"]}
    elif estimate:
        e = estimate_registration(source)
        out["estimate"] = {"focal_ratio": e.focal_ratio, "color_fx": e.cameras.color.fx, "color_fy": e.cameras.color.fy,
                           "translation_m": list(e.translation), "edge_agreement_raw": e.before,
                           "edge_agreement_estimated": e.after, "shift_px": e.shift_px,
                           "already_registered": e.registered, "frames": e.frames,
                           "camera_file_lines": e.cameras.camera_file_lines()}
    return out


def gather(source, gap: int = 10, config=None, steps: bool = False, estimate: bool = False) -> dict:
    """Everything `info` reports, as a JSON-ready dict (with `config`: the settings a run would use;
    with `steps`: the check of every reference step; with `estimate`: the colour camera estimated)."""
    import numpy as np

    from splat_core.io.checks import (
        convention_check, depth_stats, inconsistent_steps, reference_step_residuals, trajectory_length,
    )

    intr = source.intrinsics
    stamps = source.timestamps
    info = {
        "path": str(source.path),
        "format": source.format_name,
        "frames": len(source),
        "resolution": [intr.width, intr.height],
        "intrinsics": intr.to_dict(),
        "duration_s": float(stamps[-1] - stamps[0]) if len(stamps) else 0.0,
    }
    for attr in ("color_size", "depth_size"):
        if hasattr(source, attr):
            info[attr] = list(getattr(source, attr))
    depth = depth_stats(source)
    info["depth"] = depth.to_dict()
    c2w = source.reference_c2w() if source.has_reference_poses else None
    info["reference_poses"] = c2w is not None
    info["frames_with_pose"] = 0 if c2w is None else int(sum(bool((T == T).all()) for T in c2w))
    info["trajectory_length_m"] = trajectory_length(c2w)
    info["pose_check"] = convention_check(source, gap=gap).to_dict() if c2w is not None else None
    if steps and c2w is not None and len(source) > 1:
        residuals = reference_step_residuals(source)
        info["step_check"] = {"steps": len(residuals), "median_abs_dz_m": float(np.nanmedian(residuals[:, 0])),
                              "inconsistent": [{"step": [i, i + 1], "median_abs_dz_m": float(residuals[i, 0]),
                                                "fraction_within_2cm": float(residuals[i, 1])}
                                               for i in inconsistent_steps(residuals)]}
    info["registration"] = registration(source, estimate)
    warnings = list(getattr(source, "warnings", []))
    if depth.message:
        warnings.append(depth.message)
    if info["pose_check"] and info["pose_check"]["ok"] is False:
        warnings.append("pose check: " + info["pose_check"]["message"])
    for bad in info.get("step_check", {}).get("inconsistent", []):
        warnings.append(f"reference poses {bad['step'][0]} -> {bad['step'][1]}: the depth contradicts this step "
                        f"(median |dz| {_cm(bad['median_abs_dz_m'])}, {bad['fraction_within_2cm'] * 100:.0f}% "
                        f"within 2 cm); an ATE against this reference charges it to every method")
    info["warnings"] = warnings
    if config is not None:
        info["settings"] = settings(source, config)
    return info


def _cm(v):
    return "n/a" if v is None else f"{v * 100:.1f} cm"


def format_text(info: dict) -> str:
    i = info["intrinsics"]
    d = info["depth"]
    lines = [
        f"capture      {info['path']}",
        f"format       {info['format']}",
        f"frames       {info['frames']} ({info['duration_s']:.2f} s)",
        f"resolution   {info['resolution'][0]}x{info['resolution'][1]}"
        + (f" (colour {info['color_size'][0]}x{info['color_size'][1]}, depth {info['depth_size'][0]}x"
           f"{info['depth_size'][1]})" if info.get("color_size") and info["color_size"] != info["depth_size"] else ""),
        f"intrinsics   fx {i['fx']:.2f}  fy {i['fy']:.2f}  cx {i['cx']:.2f}  cy {i['cy']:.2f}",
    ]
    if d["median_m"] is None:
        lines.append(f"depth        no valid depth in frames {d['frames']}")
    else:
        lines.append(f"depth        {d['min_m']:.2f} - {d['max_m']:.2f} m, median {d['median_m']:.2f} m, "
                     f"{d['valid_fraction'] * 100:.0f}% valid (frames {', '.join(map(str, d['frames']))})")
    if info["reference_poses"]:
        lines.append(f"ref. poses   yes ({info['frames_with_pose']} of {info['frames']} frames), "
                     f"trajectory {info['trajectory_length_m']:.3f} m")
        pc = info["pose_check"]
        if pc["median_abs_dz_m"] is not None:
            alt = ", ".join(f"{k} {_cm(v)}" for k, v in pc["alternatives"].items())
            pairs = ", ".join(f"{a}->{b}" for a, b in pc["pairs"])
            lines.append(f"pose check   median |dz| {_cm(pc['median_abs_dz_m'])}, "
                         f"{pc['fraction_below_5cm'] * 100:.0f}% < 5 cm (frames {pairs}; if misread: {alt}) "
                         f"-> {'OK' if pc['ok'] else 'SUSPICIOUS'}")
        else:
            lines.append(f"pose check   {pc['message']}")
        if info.get("step_check"):
            sc = info["step_check"]
            lines.append(f"step check   {sc['steps']} steps, median |dz| {_cm(sc['median_abs_dz_m'])}, "
                         f"{len(sc['inconsistent'])} contradicted by the depth"
                         + "".join(f" ({b['step'][0]}->{b['step'][1]})" for b in sc["inconsistent"]))
    else:
        lines.append("ref. poses   no")
    lines += _registration_lines(info["registration"])
    if info.get("settings"):
        st = info["settings"]
        w, h = st["working_size"]
        lines.append(f"settings     {st['summary']}")
        lines.append(f"a run        {st['tracking_iterations']} tracking + {st['mapping_iterations']} mapping iterations "
                     f"at {w}x{h} (resolution {st['resolution']}; splatam run --config / --resolution change it)")
    for w in info["warnings"]:
        lines.append(f"warning      {w}")
    return "\n".join(lines)


def _registration_lines(reg: dict) -> list[str]:
    ea = reg["edge_agreement"]
    how = ("registered when read (two cameras in the camera file)" if reg["two_cameras"] else
           f"registered ({reg['registered_by']})" if reg.get("registered_by") else
           "registered" if reg["registered_by_reader"] else "not registered (camera file)")
    lines = [f"colour/depth {how}; edge agreement " + ("n/a (no depth edges)" if ea is None else f"{ea:.2f}")
             + " (colour gradient at depth edges / image mean; ~1 unrelated, higher = better aligned)"]
    e = reg.get("estimate")
    if e and e.get("not_estimated"):
        lines.append("estimate     already registered by its writer: not estimated (a search there can take the motion "
                     "between the colour and depth exposures for an offset: docs/formats.md, Two cameras)")
    elif e:
        tx, ty, _ = e["translation_m"]
        lines.append(f"estimate     colour focal {e['focal_ratio']:.3f} x depth (fx {e['color_fx']:.1f}), offset "
                     f"tx {tx * 100:+.2f} cm ty {ty * 100:+.2f} cm; edge agreement {e['edge_agreement_raw']:.2f} as "
                     f"stored -> {e['edge_agreement_estimated']:.2f} (frames {', '.join(map(str, e['frames']))})")
        if e["already_registered"]:
            lines.append(f"estimate     already registered (the best moves no pixel more than {e['shift_px']:.1f} px)")
        else:
            lines.append("estimate     add to the camera file (fx fy cx cy width height stay the depth camera's):")
            lines += [f"  {line}" for line in e["camera_file_lines"]]
    return lines


def main(args) -> int:
    from app.run_setup import load_run_config
    from splat_core.io import open_capture
    from splat_core.run import resolve_device

    source = open_capture(args.input, format=args.format)
    config = load_run_config(args.config, source.format_name, resolve_device("auto"), args.resolution)
    info = gather(source, gap=args.gap, config=config, steps=args.steps, estimate=args.estimate_registration)
    print(json.dumps(info, indent=2) if args.json else format_text(info))
    return 0
