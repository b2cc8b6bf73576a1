"""The human-readable form of a `posedesc bench` result: one small table per section, then the targets."""

from __future__ import annotations


def _num(x: float | None, digits: int = 1) -> str:
    if x is None:
        return "-"
    if abs(x) >= 1000:
        return f"{x:,.0f}"
    return f"{x:.{digits}f}"


def _mb(x: float | None) -> str:
    return "-" if x is None else f"{x / 2**20:,.0f}"


def _table(title: str, header: list[str], rows: list[list[str]]) -> list[str]:
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    fmt = "  ".join(f"{{:{'<' if i == 0 else '>'}{w}}}" for i, w in enumerate(widths))
    return ["", title, fmt.format(*header), *(fmt.format(*r) for r in rows)]


def _guards(gd: dict) -> list[str]:
    """The guards section: hostile uploads over HTTP, meshes refused from their counts, the fuzz cases, a
    busy port."""
    rows = [
        [name, f"{u['bytes']:,}", f"{u['status']}" + ("" if u["status"] == u["expected"] else f" (not {u['expected']})"),
         _num(u["median_ms"]), _num(u["max_ms"])]
        for name, u in gd["uploads"].items()
    ]  # fmt: skip
    lines = _table(
        "hostile uploads refused by the service (loopback), request to answer; ms",
        ["upload", "bytes", "status", "median", "max"],
        rows,
    )
    rows = [
        [
            name,
            f"{d['bytes']:,}",
            "yes" if d["refused"] else "NO",
            _num(d["median_ms"], 2),
            _num(d["max_ms"], 2),
        ]
        for name, d in gd["declaring"].items()
    ]
    lines += _table(
        "meshes refused from what they declare, before parsing (load_mesh); ms",
        ["file", "bytes", "refused", "median", "max"],
        rows,
    )
    fz, bp = gd["fuzz"], gd["busy_port"]
    lines += _table(
        f"damaged meshes (load_mesh), {fz['cases']} cases: {fz['loaded']} loaded, {fz['refused']} refused, "
        f"{fz['other_error']} other errors; ms",
        ["p50", "p99", "max", *(f"max {f}" for f in fz["by_format_max_ms"])],
        [[_num(fz["p50_ms"], 2), _num(fz["p99_ms"], 2), _num(fz["max_ms"], 2),
          *(_num(v, 2) for v in fz["by_format_max_ms"].values())]],
    )  # fmt: skip
    lines.append(
        f"posedesc serve on a busy port: exit {', '.join(map(str, bp['exit_codes']))} after "
        f"{bp['median_s']:.2f} s (median of {bp['runs']}; max {bp['max_s']:.2f} s)"
    )
    return lines


def _roll(ro: dict, summary: dict) -> list[str]:
    """The roll section: in-process per model and set-up, then the served set-up."""
    n_obj = ro["objects"]
    rows = []
    for label, setups in ro["in_process"].items():
        fp = ro["models"][label]["fingerprint"][:8]
        names = {"upright": "upright", "roll": f"in-plane, {setups['roll'].get('index', 'index')}"}
        names["exact"] = "in-plane, exact (flat)"
        for setup in ("upright", "roll", "exact"):
            if setup not in setups:
                continue
            r = setups[setup]
            for n, row in r["by_turns"].items():
                st = row["stages_median_ms"]
                rows.append(
                    [
                        f"{label} ({fp}), {names[setup]}",
                        f"{r['templates']:,}",
                        n,
                        *(_num(row[f"{q}_ms"], 2) for q in ("p50", "p90", "p99")),
                        _num(st["embed"], 2),
                        _num(st["search"], 2),
                    ]
                )
    runs = [row["runs"] for s in ro["in_process"].values() for row in s["roll"]["by_turns"].values()][:1]
    lines = _table(
        f"from a decoded patch to the answer (service.recognition.recognise_decoded), {ro['modality']}, "
        f"{n_obj} objects, k = {ro['k']} ({runs[0] if runs else 0} calls each)",
        ["model, set-up", "templates", "turns", "p50 ms", "p90", "p99", "embed", "k-NN"],
        rows,
    )
    if (lm := summary.get(f"linemod_median_ms_{n_obj}")) is not None:
        lines.append(f"LineMOD, same objects count, upright templates (recognition section): {_num(lm)} ms")
    lines += _stages(ro)
    if sv := ro.get("server"):
        rows = [
            [
                "640x480 frame" if req == "frame_640x480" else "64 px patch",
                *(_num(sv[req][f"{q}_ms"]) for q in ("p50", "p90", "p99")),
                _num(sv[req]["server_total_median_ms"]),
            ]
            for req in ("frame_640x480", "patch")
        ]
        per = ", ".join(f"{m} {n:,}" for m, n in sv["templates_per_object"].items())
        lines += _table(
            f"POST /recognize over HTTP, 1 client, {sv['objects']} objects, served model {sv['model']} "
            f"({sv['fingerprint'][:8]}), query turns {sv['query_turns']}; templates per object: {per}",
            ["request", "p50 ms", "p90 ms", "p99 ms", "in service ms"],
            rows,
        )
        g = sv["register"]
        lines += _table(
            f"POST /objects, {g['faces']:,}-face mesh, models {', '.join(g['models'])}, store of "
            f"{g['store_objects_before']} objects (median of {g['repeats']}; first one {g['cold_s']:.2f} s)",
            ["request s", "render s", "embed s", "store s", "in service s"],
            [
                [
                    _num(g["wall_s"], 2),
                    *(_num(g.get(k), 2) for k in ("render_s", "embed_s", "store_s", "total_s")),
                ]
            ],
        )
    return lines


def _stages(ro: dict) -> list[str]:
    """The primary model's in-plane set-up, a row per key of the pipeline's `timings_ms` (its stages,
    then the sums), median and p90 for each query-turn count."""
    turns = [k.rsplit("_q", 1)[1] for k in ro if k.startswith(f"stages_ms_{ro['objects']}_q")]
    if not turns:
        return []
    med = {n: ro[f"stages_ms_{ro['objects']}_q{n}"] for n in turns}
    p90 = {n: ro[f"stages_p90_ms_{ro['objects']}_q{n}"] for n in turns}
    keys = list(dict.fromkeys(k for n in turns for k in med[n]))
    rows = [[k, *(f"{_num(med[n].get(k), 2)} / {_num(p90[n].get(k), 2)}" for n in turns)] for k in keys]
    lines = _table(
        f"per stage (timings_ms), {ro['primary']} model, in-plane templates, {ro['objects']} objects; "
        "median / p90 ms",
        ["stage", *(f"{n} turn{'s' if n != '1' else ''}" for n in turns)],
        rows,
    )
    if pr := ro.get("profile"):
        lines.append(f"profile of {pr['calls']} calls ({pr['samples']:,} stack samples): {pr['dir']}")
    return lines


def _detect(de: dict) -> list[str]:
    """The detect section: a row per object count and frame kind (p50 / p90 of the detector's total, the
    median of each stage, the proposals verified), then the registrations by window class."""
    rows = []
    for n, row in de["by_objects"].items():
        for kind, label in (("colour", "colour (rgb)"), ("rgbd", "Kinect RGB-D")):
            if (r := row.get(kind)) is None:
                continue
            st = r["stages_median_ms"]
            rows.append(
                [
                    n,
                    label,
                    str(r["runs"]),
                    _num(r["proposals_median"], 0),
                    _num(r["p50_ms"]),
                    _num(r["p90_ms"]),
                    *(_num(st.get(k)) for k in ("decode", "propose", "verify")),
                    _num(r["verify_ms_per_proposal"]),
                ]
            )
    if not rows:
        return []
    fr = de["frames"]["colour"]
    lines = _table(
        f"objects found in a whole 640x480 frame in-process (service.detection.detect); colour: LM-O scene "
        f"{fr['scene']} frames {', '.join(map(str, fr['frames']))}; ms",
        [
            "objects",
            "frame",
            "runs",
            "proposals",
            "p50",
            "p90",
            "decode",
            "propose",
            "verify",
            "per proposal",
        ],
        rows,
    )
    reg = de["register"]
    if reg["objects"]:
        by = ", ".join(
            f"{w} mm: {b['objects']} at {b['median_s']:.2f} s" for w, b in reg["by_window_mm"].items()
        )
        lines.append(
            f"registrations (index.templates.register, the window following the size): median {reg['median_s']:.2f} s "
            f"of {reg['objects']}; by window: {by}"
        )
    return lines


def render(result: dict) -> str:
    m, th, sec = result["machine"], result["threads"], result["sections"]
    lines = [
        f"posedesc bench: {m['cores_usable']} cores ({m['cpu']}), load {m['load_average_at_start'][0]:.1f} at start, "
        f"{m['load_average_at_end'][0]:.1f} at end; threads: onnxruntime {th['onnxruntime_intra_op']}, "
        f"FAISS {th['faiss_omp']}, OpenCV {th['opencv']}; {result['seconds']['total']:.0f} s",
    ]
    if d := sec.get("descriptor"):
        lines += _table(
            f"descriptor throughput, {d['modality']}, {d['patches']} patches, median of {d['repeats']} "
            f"(a descriptor is {d['descriptor_bytes']['ours']:,} B, HOG's {d['descriptor_bytes']['hog']:,} B)",
            ["method", "patches/s", "vs HOG"],
            [
                ["descriptor only: ours (onnxruntime), batch 1", _num(d["onnx_b1_patches_per_s"]), _num(d["onnx_vs_hog_ratio_b1"], 2) + "x"],
                ["descriptor only: ours (onnxruntime), batch 256", _num(d["onnx_b256_patches_per_s"]), _num(d["onnx_vs_hog_ratio_b256"], 2) + "x"],
                ["descriptor only: HOG", _num(d["hog_only_patches_per_s"]), "1x"],
                ["from the patch: ours, batch 1", _num(d["ours_b1_patches_per_s"]), _num(d["ours_vs_hog_throughput_ratio_b1"], 2) + "x"],
                ["from the patch: ours, batch 256", _num(d["ours_b256_patches_per_s"]), _num(d["ours_vs_hog_throughput_ratio_b256"], 2) + "x"],
                ["from the patch: HOG", _num(d["hog_patches_per_s"]), "1x"],
            ],
        )  # fmt: skip
    if r := sec.get("recognition"):
        rows = []
        for n, row in r["by_objects"].items():
            lm = row.get("linemod")
            rows.append(
                [
                    n,
                    f"{row['templates']:,}",
                    _num(row["ours"]["p50_ms"], 2),
                    _num(row["ours"]["embed_median_ms"], 2),
                    _num(row["ours"]["search_median_ms"], 2),
                    _num(lm["median_ms"] if lm else None),
                    _num(row.get("speedup")) + ("x" if row.get("speedup") else ""),
                ]
            )
        runs = [row["ours"]["runs"] for row in r["by_objects"].values()][:1]
        runs_lm = [row["linemod"]["runs"] for row in r["by_objects"].values() if "linemod" in row][:1]
        lines += _table(
            f"one recognition in-process, {r['modality']}, k = {r['k']} (ours: p50 of {runs[0] if runs else 0}, "
            f"embed and k-NN apart; LineMOD: median of {runs_lm[0] if runs_lm else 0})",
            ["objects", "templates", "ours ms", "embed", "k-NN", "LineMOD ms", "speedup"],
            rows,
        )
    if k := sec.get("knn"):
        rows = []
        for n, row in k["by_size"].items():
            ivf = row.get("ivf") or {}
            rows.append(
                [
                    f"{int(n):,}",
                    _num(row["flat"]["median_ms"], 3),
                    _mb(row["flat"]["memory_bytes"]),
                    _num(ivf.get("median_ms"), 3),
                    _mb(ivf.get("memory_bytes")),
                    _num(ivf.get("recall_at_k"), 3),
                ]
            )
        lines += _table(
            f"k-NN, {k['dim']}-d, k = {k['k']}, one query, {k['threads']['search']} thread "
            f"(IVF nlist {k['ivf']['nlist']}, nprobe {k['ivf']['nprobe']})",
            ["templates", "exact ms", "exact MB", "IVF ms", "IVF MB", f"IVF recall@{k['k']}"],
            rows,
        )
    if h := sec.get("http"):
        rows = [
            [
                c,
                _num(row["p50_ms"]),
                _num(row["p99_ms"]),
                _num(row["requests_per_s"]),
                _num(row["server_total_median_ms"]),
            ]
            for c, row in h["by_concurrency"].items()
        ]
        f = h["frame_640x480"]
        rows.append(
            [
                "1, 640x480 frame",
                _num(f["p50_ms"]),
                _num(f["p99_ms"]),
                _num(f["requests_per_s"]),
                _num(f["server_total_median_ms"]),
            ]
        )
        lines += _table(
            f"POST /recognize over HTTP, loopback, {h['objects']} objects, {h['modality']} patch "
            f"({h['requests_per_level']} requests x {h['rounds']} rounds per level)",
            ["clients", "p50 ms", "p99 ms", "req/s", "in service ms"],
            rows,
        )  # fmt: skip
    if g := sec.get("register"):
        window = f" ({g['window_mm']:g} mm window for its size)" if g.get("window_mm") else ""
        lines += _table(
            f"POST /objects, {g['faces']:,}-face mesh{window}, models {', '.join(g['models'])}, store of "
            f"{g['store_objects_before']} objects (median of {g['repeats']}; first one {g['cold_s']:.2f} s)",
            ["request s", "render s", "embed s", "store s", "in service s"],
            [
                [
                    _num(g["wall_s"], 2),
                    *(_num(g.get(k), 2) for k in ("render_s", "embed_s", "store_s", "total_s")),
                ]
            ],
        )
    if ro := sec.get("roll"):
        lines += _roll(ro, result.get("summary", {}))
    if t := sec.get("train"):
        lines += _table(
            f"training step, {t['modality']}, {t['torch_threads']} torch threads, batch of "
            f"{t['samples_per_batch']} samples = {t['patches_per_batch']} patches (median of {t['steps']})",
            ["patches/s", "samples/s", "step ms"],
            [[_num(t["train_patches_per_s"]), _num(t["train_samples_per_s"]), _num(t["step_median_ms"])]],
        )
    if mv := sec.get("milvus"):
        rows = []
        for n, row in mv["by_size"].items():
            rec, reg = row["recognition"], row["registration"]
            rows.append(
                [
                    f"{int(n):,} ({row['filled']})",
                    f"{_num(rec['embedded']['p50_ms'], 2)} / {_num(rec['embedded']['p99_ms'], 2)}",
                    f"{_num(rec['milvus']['p50_ms'], 2)} / {_num(rec['milvus']['p99_ms'], 2)}",
                    _num(reg["embedded"]["p50_ms"]) if "embedded" in reg else "-",
                    _num(reg["milvus"]["p50_ms"]),
                    _num(row["recall_at_k"], 3),
                ]
            )
        lines += _table(
            f"template store: embedded (FAISS flat + SQLite) vs Milvus ({mv['milvus']['uri']}; HNSW), "
            f"{mv['dim']}-d, k = {mv['k']}; ms",
            ["templates", "embedded answers p50 / p99", "Milvus answers p50 / p99", "embedded add_object",
             "Milvus add_object", f"Milvus recall@{mv['k']}"],
            rows,
        )  # fmt: skip
    if me := sec.get("memory"):
        lines += _memory(me)
    if gd := sec.get("guards"):
        lines += _guards(gd)
    if de := sec.get("detect"):
        lines += _detect(de)
    if (fi := sec.get("fit")) and fi["rows"]:
        from benchmarks.fit import table as fit_rows

        mm = fi["models_made"]
        lines += _table(
            f"the pose fit (pose_fit 1, one answer a call) beside the call without it, in-process; each object's "
            f"models made in (median) colour {mm['colour_s_median']:.2f} s, {mm['colour_bytes_max'] / 1024:.0f} kB, "
            f"depth {mm['depth_s_median'] * 1e3:.0f} ms, {mm['depth_bytes_max'] / 1024:.0f} kB; ms",
            [
                "frames",
                "model",
                "calls",
                "fit p50",
                "fit p90",
                "call p50 off",
                "call p50 on",
                "on/off",
                "moved",
            ],
            list(fit_rows(fi)),
        )
    if (pr := (sec.get("milvus") or {}).get("propagation")) is not None:
        lines += _table(
            f"replicas: two stores on one Milvus and one shared directory (each polls every "
            f"{pr['poll_seconds'] * 1e3:.0f} ms): from the call's start until the other store shows the change; ms",
            ["change", "seen p50", "seen max", "call p50", "runs"],
            [
                [what, *(_num(pr[what][k]) for k in ("seen_p50_ms", "seen_max_ms", "call_p50_ms")), str(pr[what]["runs"])]
                for what in ("registration", "deletion")
            ],
        )  # fmt: skip
    starts = [
        r["replica_start"]
        for r in (sec.get("milvus") or {}).get("by_size", {}).values()
        if "replica_start" in r
    ]
    if starts:
        lines += _table(
            "a replica's store opened after the registrations through another: from opening it until its answers "
            "equal the other's; s",
            ["objects", "p50", "max", "runs"],
            [[str(r["objects"]), _num(r["p50_s"], 2), _num(r["max_s"], 2), str(r["runs"])] for r in starts],
        )
    if result.get("targets"):
        rows = []
        for v in result["targets"].values():
            val = v["value"]
            shown = ", ".join(_num(x) for x in val) if isinstance(val, list) else _num(val, 2)
            rows.append([v["what"], v["target"], shown, {True: "yes", False: "NO", None: "-"}[v["met"]]])
        lines += _table("targets", ["", "target", "measured", "met"], rows)
    for note in result.get("notes", []) + [f"capped: {c}" for c in result.get("capped", [])]:
        lines.append(f"note: {note}")
    return "\n".join(lines)


def _memory(me: dict) -> list[str]:
    """The memory section: per store size, the resident memory after a query and the disk, per object."""
    rows = []
    for n, row in me["by_count"].items():
        acc = row["accounting"]
        rows.append(
            [
                f"{int(n):,}",
                f"{row['queried']['VmRSS'] / 1e6:,.0f}",
                f"{row['queried']['RssAnon'] / 1e6:,.0f}",
                f"{row['queried']['RssFile'] / 1e6:,.0f}",
                f"{acc['ram_anonymous_bytes_per_object'] / 1e6:.2f}",
                f"{acc['ram_mapped_bytes_per_object'] / 1e6:.2f}",
                f"{acc['disk_bytes_per_object']['total'] / 1e6:.2f}",
            ]
        )
    lines = _table(
        "memory: the service's state after one query per model (VmRSS = RssAnon + RssFile, MB), and "
        "the store's accounting per object (MB)",
        ["objects", "VmRSS", "RssAnon", "RssFile", "heap / object", "mapped / object", "disk / object"],
        rows,
    )
    if slope := me.get("slope_mb_per_object"):
        lines.append(
            f"slope: {slope['queried_VmRSS']} MB resident per object ({slope['queried_RssAnon']} heap), "
            f"{me['disk_mb_per_object']} MB on disk"
        )
    return lines
