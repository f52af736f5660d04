"""Reconstruct a whole slide on a Dask cluster: every field of view is its own FPM
dataset, reconstructed by the `fpm` Python package on a worker, each into its own
output directory. Dask does the scheduling; this script only maps fields to it.

    python examples/slide_dask.py SLIDE_DIR OUT_ROOT [--workers 2] [--passes 10]
    python examples/slide_dask.py SLIDE_DIR OUT_ROOT --scheduler tcp://HOST:8786
    python examples/slide_dask.py SCAN_DIR [--upsample 2]; fpm stitch SCAN_DIR

SLIDE_DIR holds one dataset directory per field (each with a dataset.toml). A scan's
directory (with scan.json, as `fpm scan` writes it) needs no OUT_ROOT: each field goes
into its own `reconstruction/`, with the scan's calibration (the field's own, else the
first field's), where `fpm stitch` reads it back and joins the fields. Without
--scheduler a local cluster is started, its scheduler, workers and dashboard bound to
127.0.0.1 only. Fields already done are skipped, and a field is moved into place only
when complete, so a stopped run resumes (as `fpm reconstruct --out-root` does).
"""

import argparse
import json
import os
import shutil
import time
from pathlib import Path


def reconstruct_field(dataset_dir, out, passes, upsample, geometry):
    """One field into `out`, on a worker: skipped when done, else reconstructed and
    saved."""
    import fpm

    name = Path(dataset_dir).name
    out = Path(out)
    if (out / "report.json").is_file():
        return {"field": name, "status": "skipped"}
    partial = out.parent / f".{out.name}.partial"
    shutil.rmtree(partial, ignore_errors=True)
    began = time.perf_counter()
    try:
        dataset = fpm.Dataset.load(dataset_dir)
        result = fpm.reconstruct(dataset, geometry=geometry, passes=passes, upsample=upsample)
        result.save(partial)
    except (fpm.DatasetError, fpm.FpmError) as error:
        shutil.rmtree(partial, ignore_errors=True)
        return {"field": name, "status": "failed", "error": str(error)}
    shutil.rmtree(out, ignore_errors=True)
    partial.rename(out)
    return {"field": name, "status": "done", "seconds": time.perf_counter() - began}


def fields_of(slide, out_root):
    """The slide's fields, each (dataset directory, output directory, calibration or
    None): a scan's from its scan.json, each into its own reconstruction/ with the
    scan's calibration; else every dataset directory in name order, each into
    OUT_ROOT/<name>."""
    slide = Path(slide)
    manifest = slide / "scan.json"
    if manifest.is_file():
        datasets = [slide / f["dataset"] for f in json.loads(manifest.read_text())["fields"]]
        first = datasets[0] / "calibration.json" if datasets else None

        def calibration(d):
            own = d / "calibration.json"
            if own.is_file():
                return str(own)
            return str(first) if first is not None and first.is_file() else None

        return [(d, d / "reconstruction", calibration(d)) for d in datasets]
    if out_root is None:
        raise SystemExit(f"{slide}: not a scan (no scan.json); give OUT_ROOT for its fields")
    return [
        (p, Path(out_root) / p.name, None)
        for p in sorted(slide.iterdir())
        if (p / "dataset.toml").is_file()
    ]


def run(slide, out_root=None, workers=2, scheduler=None, passes=10, upsample=4, geometry=None):
    """Reconstruct every field of `slide` (into `out_root`, or a scan's own
    reconstruction/ directories); returns a summary dict."""
    from dask.distributed import Client, LocalCluster

    fields = fields_of(slide, out_root)
    if not fields:
        raise SystemExit(f"{slide}: no dataset directories (none with a dataset.toml)")
    for _, out, _ in fields:
        out.parent.mkdir(parents=True, exist_ok=True)
    if scheduler:
        cluster = None
        client = Client(scheduler)
    else:
        # Loopback only; each worker one process, its reconstruction using its share
        # of the cores.
        threads = max(1, (os.cpu_count() or 1) // workers)
        cluster = LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            scheduler_port=0,
            dashboard_address="127.0.0.1:0",
            env={"RAYON_NUM_THREADS": str(threads)},
        )
        client = Client(cluster)
    began = time.perf_counter()
    try:
        addresses = [client.scheduler.address, *client.scheduler_info()["workers"]]
        futures = [
            client.submit(
                reconstruct_field,
                str(dataset),
                str(out),
                passes=passes,
                upsample=upsample,
                geometry=geometry or calibration,
                pure=False,
            )
            for dataset, out, calibration in fields
        ]
        results = client.gather(futures)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    minutes = (time.perf_counter() - began) / 60
    done = sum(r["status"] == "done" for r in results)
    return {
        "workers": workers if cluster is not None else None,
        "done": done,
        "skipped": sum(r["status"] == "skipped" for r in results),
        "failed": sum(r["status"] == "failed" for r in results),
        "fields_per_minute": done / minutes if minutes > 0 else 0.0,
        "addresses": addresses + [client.dashboard_link or ""],
        "fields": results,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("slide", help="directory of field datasets, or a scan's directory")
    parser.add_argument(
        "out_root",
        nargs="?",
        help="one output directory per field goes here (a scan's fields: their own reconstruction/)",
    )
    parser.add_argument("--workers", type=int, default=2, help="local cluster's worker processes")
    parser.add_argument("--scheduler", help="an existing cluster's scheduler address instead")
    parser.add_argument("--passes", type=int, default=10)
    parser.add_argument("--upsample", type=int, default=4)
    parser.add_argument(
        "--calibration",
        help="calibration.json of the rig (default: a scan's own, else each dataset's nominal array)",
    )
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    args = parser.parse_args()
    summary = run(
        args.slide,
        args.out_root,
        workers=args.workers,
        scheduler=args.scheduler,
        passes=args.passes,
        upsample=args.upsample,
        geometry=args.calibration,
    )
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        for field in summary["fields"]:
            print(f"{field['field']}: {field['status']} {field.get('error', '')}".rstrip())
        print(
            f"{summary['done']} reconstructed, {summary['skipped']} already done,"
            f" {summary['failed']} failed; {summary['fields_per_minute']:.1f} fields per minute"
        )
    raise SystemExit(1 if summary["failed"] else 0)


if __name__ == "__main__":
    main()
