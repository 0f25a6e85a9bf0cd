"""The batch: plan each capture (skip / failed before / submit), submit one task per capture to
the cluster, print a line per capture as it finishes under a progress bar, keep the summary up
to date after each, write the report at the end (Ctrl-C included), and return the exit code.

Exit code: 0 when no capture failed, else the number of failed captures (at most 99); 130 after
Ctrl-C (finished runs kept, the summary and report written; the next batch resumes the rest).
"""

from __future__ import annotations

import sys
import time
import uuid
from dataclasses import asdict
from pathlib import Path

from . import state
from .summary import counts, make_row, write_summary

MAX_EXIT_CODE = 99


def _line(row: dict) -> str:
    parts = [f"{row['status']:<11} {row['name']}"]
    if row["status"] in ("failed", "interrupted", "pending") and row.get("error"):
        return parts[0] + f": {row['error']}"
    if row.get("frames") is not None:
        parts.append(f"{row['frames']} frames")
    if row.get("s_per_frame") is not None:
        parts.append(f"{row['s_per_frame']:.2f} s/frame")
    if row.get("ate_rmse_cm") is not None:
        parts.append(f"ATE {row['ate_rmse_cm']:.2f} cm")
    if row.get("psnr") is not None:
        parts.append(f"PSNR {row['psnr']:.1f} dB")
    if row.get("batch_seconds") is not None:
        parts.append(f"{row['batch_seconds']:.1f} s")
    return parts[0] + (": " + ", ".join(parts[1:]) if len(parts) > 1 else "")


class Batch:
    def __init__(self, captures, out_root: Path, opts, retry_failed: bool = False, quiet: bool = False):
        self.captures, self.out_root, self.opts = captures, Path(out_root), opts
        self.retry_failed, self.quiet = retry_failed, quiet
        self.results: dict[str, dict] = {}
        self.rows: dict[str, dict] = {}
        self.meta = dict(out=str(self.out_root), options=asdict(opts), started=time.time(), cluster="")
        self.started = time.time()

    def say(self, text: str) -> None:
        if not self.quiet:
            print(text, file=sys.stderr, flush=True)

    def plan(self) -> list:
        """The captures to submit; the others get their result now (skipped, or failed before)."""
        todo = []
        for cap in self.captures:
            run_dir = self.out_root / cap.name
            action = state.plan(run_dir, self.opts.refine, list(self.opts.exports), self.retry_failed)
            if action == "skip":
                self.record(cap, dict(status="skipped"))
            elif action == "failed":
                error = state.read_status(run_dir).get("error") or "failed"
                self.record(cap, dict(status="failed", error=f"{error} (failed in an earlier batch; "
                                      "--retry-failed reruns it)"))
            else:
                todo.append(cap)
        return todo

    def record(self, cap, result: dict) -> dict:
        self.results[cap.name] = result
        self.rows[cap.name] = row = make_row(cap, result, self.out_root)
        return row

    def all_rows(self) -> list[dict]:
        out = []
        for cap in self.captures:
            if cap.name not in self.rows:    # no result came back: running at Ctrl-C, or not started
                st = state.read_status(self.out_root / cap.name)
                if st.get("status") in ("done", "resumed", "failed") and st.get("started", 0) >= self.started:
                    self.record(cap, dict(st, name=cap.name))     # it ended just before the result came back
                    out.append(self.rows[cap.name])
                    continue
                began = st.get("status") in ("running", "interrupted") and st.get("started", 0) >= self.started
                self.rows[cap.name] = make_row(cap, dict(status="interrupted" if began else "pending",
                                                         error="stopped by Ctrl-C; the next batch resumes it"
                                                         if began else "not started"), self.out_root)
                if began:
                    state.update_status(self.out_root / cap.name, status="interrupted")
            out.append(self.rows[cap.name])
        return out

    def write(self, final: bool = False) -> None:
        rows = [self.rows[c.name] if c.name in self.rows else make_row(c, None, self.out_root)
                for c in self.captures] if not final else self.all_rows()
        self.meta["ended"] = time.time() if final else None
        write_summary(self.out_root, rows, self.meta)
        if final:
            from .report import write_report
            write_report(self.out_root, self.captures, rows, self.meta)

    def run(self, scheduler: str | None, layout_args: dict) -> int:
        from tqdm import tqdm

        from .cluster import open_client
        from .task import run_capture

        self.out_root.mkdir(parents=True, exist_ok=True)
        todo = self.plan()
        tally = counts(list(self.rows.values()))
        self.say(f"batch: {len(self.captures)} capture(s) -> {self.out_root}: {len(todo)} to run"
                 + "".join(f", {n} {s}" for s, n in tally.items() if n)
                 + ("" if not tally["failed"] else " (--retry-failed reruns those)"))
        for name, row in self.rows.items():
            self.say(_line(row))
        self.write()
        interrupted = False
        if todo:
            try:
                interrupted = self._submit(todo, scheduler, layout_args, tqdm, open_client, run_capture)
            except KeyboardInterrupt:
                interrupted = True
        self.write(final=True)
        rows = [self.rows[c.name] for c in self.captures]
        tally = counts(rows)
        self.say(", ".join(f"{n} {s}" for s, n in tally.items() if n)
                 + f"; summary: {self.out_root / 'summary.md'}, report: {self.out_root / 'index.html'}")
        # Ctrl-C reaches the whole process group: a run can stop (and report "interrupted") before the
        # KeyboardInterrupt surfaces here, or distributed's event loop may swallow it; either way it was one.
        if interrupted or tally.get("interrupted"):
            self.say("interrupted: finished runs are kept; the same command resumes the rest")
            return 130
        return min(tally["failed"], MAX_EXIT_CODE)

    def _submit(self, todo, scheduler, layout_args, tqdm, open_client, run_capture) -> bool:
        from dataclasses import replace

        from distributed import Event, as_completed

        token = uuid.uuid4().hex[:8]
        with open_client(scheduler, layout_args) as (client, layout, lines):
            for line in lines:
                self.say(line)
            self.meta["cluster"] = lines[0]
            opts = replace(self.opts, cores=self.opts.cores or layout.cores_per_run, gpu_slots=layout.gpu_slots,
                           stop_event=f"splatam-batch-stop-{token}")
            stop = Event(opts.stop_event, client=client)
            by_key = {}
            for cap in todo:
                fut = client.submit(run_capture, cap, str(self.out_root.resolve()), opts, key=f"{cap.name}-{token}",
                                    resources=layout.task_resources, pure=False)
                by_key[fut.key] = (cap, fut)
            bar = tqdm(total=len(todo), unit="capture", disable=self.quiet, dynamic_ncols=True, file=sys.stderr)
            try:
                for fut in as_completed([f for _, f in by_key.values()]):
                    cap = by_key[fut.key][0]
                    result = self._result(cap, fut)
                    row = self.record(cap, result)
                    bar.write(_line(row), file=sys.stderr)
                    bar.update(1)
                    self.write()
            except KeyboardInterrupt:
                bar.close()
                self.say("stopping: telling the running captures to stop (their checkpoints are kept)")
                try:
                    stop.set()
                    for _, f in by_key.values():
                        f.cancel()
                    time.sleep(2)
                except Exception:
                    pass
                return True
            bar.close()
        return False

    def _result(self, cap, fut) -> dict:
        try:
            return fut.result()
        except Exception as e:     # KilledWorker: its worker died ALLOWED_FAILURES+1 times; or a task error
            kind = type(e).__name__
            error = (f"the worker running it died {1 + self._allowed_failures()} times (out of memory? killed?)"
                     if kind == "KilledWorker" else f"{kind}: {e}".splitlines()[0])
            state.update_status(self.out_root / cap.name, status="failed", error=error)
            return dict(name=cap.name, status="failed", error=error)

    @staticmethod
    def _allowed_failures() -> int:
        import dask
        return int(dask.config.get("distributed.scheduler.allowed-failures", 3))
