"""Run one function over many items, in this process or in worker processes."""

from __future__ import annotations


def each_done(fn, items, *args, jobs: int = 1):
    """Yield ``(item, fn(item, *args))`` for every item, in the order they finish.

    With ``jobs`` 1 (or a single item) in this process, in order; otherwise in at most ``jobs``
    spawned worker processes (fresh interpreters: ``fn`` and its arguments must pickle, and no
    state is shared with the caller). An exception in ``fn`` is raised here.
    """
    items = list(items)
    if jobs == 1 or len(items) <= 1:
        for item in items:
            yield item, fn(item, *args)
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    with ProcessPoolExecutor(max_workers=min(jobs, len(items)),
                             mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {pool.submit(fn, item, *args): item for item in items}
        for f in as_completed(futures):
            yield futures[f], f.result()
