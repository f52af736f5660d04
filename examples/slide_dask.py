"""Reconstruct a whole slide on a Dask cluster: every field of view is its own FPM
dataset, reconstructed by the `fpm` Python package on a worker, each into its own
output directory. Dask does the scheduling; this script only maps fields to it.

    python examples/slide_dask.py SLIDE_DIR OUT_ROOT [--workers 2] [--passes 10]
    python examples/slide_dask.py SLIDE_DIR OUT_ROOT --scheduler tcp://HOST:8786

SLIDE_DIR holds one dataset directory per field (each with a dataset.toml). Without
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


def reconstruct_field(dataset_dir, out_root, passes, upsample, geometry):
    """One field, on a worker: skipped when done, else reconstructed and saved."""
    import fpm

    name = Path(dataset_dir).name
    out = Path(out_root) / name
    if (out / "report.json").is_file():
        return {"field": name, "status": "skipped"}
    partial = Path(out_root) / f".{name}.partial"
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


def fields_of(slide):
    """The slide's dataset directories, in name order."""
    return sorted(p for p in Path(slide).iterdir() if (p / "dataset.toml").is_file())


def run(slide, out_root, workers=2, scheduler=None, passes=10, upsample=4, geometry=None):
    """Reconstruct every field of `slide` into `out_root`; returns a summary dict."""
    from dask.distributed import Client, LocalCluster

    fields = fields_of(slide)
    if not fields:
        raise SystemExit(f"{slide}: no dataset directories (none with a dataset.toml)")
    Path(out_root).mkdir(parents=True, exist_ok=True)
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
        futures = client.map(
            reconstruct_field,
            [str(f) for f in fields],
            out_root=str(out_root),
            passes=passes,
            upsample=upsample,
            geometry=geometry,
            pure=False,
        )
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
    parser.add_argument("slide", help="directory of field datasets")
    parser.add_argument("out_root", help="one output directory per field goes here")
    parser.add_argument("--workers", type=int, default=2, help="local cluster's worker processes")
    parser.add_argument("--scheduler", help="an existing cluster's scheduler address instead")
    parser.add_argument("--passes", type=int, default=10)
    parser.add_argument("--upsample", type=int, default=4)
    parser.add_argument("--calibration", help="calibration.json of the rig (default: each dataset's nominal array)")
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
