"""`splatam batch`: many captures, one ordinary `splatam run` each, distributed by Dask.

    captures.py   which captures (arguments, --list FILE) and their run-folder names
    state.py      DIR/<name>/batch_status.json: what happened to a capture, what the next batch does
    task.py       one capture's task on a Dask worker: run / resume, refine, exports, in child processes
    child.py      the child process: dies with its worker (Linux), then runs `splatam ...`
    cluster.py    a LocalCluster on 127.0.0.1, or a running cluster by address; resources per run
    driver.py     submit the tasks, show progress, collect results, Ctrl-C, exit code
    summary.py    DIR/summary.csv, summary.json, summary.md (atomic)
    report.py     DIR/index.html: the table, a trajectory plot from above per capture, links to exports

Only `cluster.py` and `driver.py` import dask; the rest is plain Python so the summary and the
report can be tested without a cluster. None of it imports torch (the runs are child processes):
run-folder paths and reading come from splat_core.run.run_folder.RunFolder, atomic writes from
splat_core.io.atomic.
"""
