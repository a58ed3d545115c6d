"""Running a study's independent tasks, serially or in a pool of processes, with a progress bar."""

from __future__ import annotations

import sys
from concurrent.futures import ProcessPoolExecutor

from tqdm.auto import tqdm

__all__ = ["map_tasks"]


def map_tasks(function, tasks, workers: int, desc: str, unit: str = "run", progress: bool = True) -> list:
    """``[function(task) for task in tasks]``, in order.

    With ``workers > 1`` the tasks run in a :class:`~concurrent.futures.ProcessPoolExecutor`
    (``function`` must be picklable: a module-level function). The tqdm bar is shown only when
    ``progress`` is set and stderr is a terminal.
    """
    tasks = list(tasks)
    bar = tqdm(total=len(tasks), desc=desc, unit=unit, disable=not (progress and sys.stderr.isatty()))
    results = []
    try:
        if workers <= 1:
            for task in tasks:
                results.append(function(task))
                bar.update()
        else:
            with ProcessPoolExecutor(max_workers=workers) as pool:
                for result in pool.map(function, tasks, chunksize=1):
                    results.append(result)
                    bar.update()
    finally:
        bar.close()
    return results
