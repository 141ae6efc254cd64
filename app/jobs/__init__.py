"""Background jobs, of any kind: the runner (runner.py: thread jobs and process jobs, their time limits, cancel,
pause and resume, the versioned snapshots), its worker processes (pool.py), the worker's side of a process job
(worker.py: what runs in the spawned process, light to import) and the snapshot every reader gets (snapshot.py:
the store keeps it, the API answers it). What a kind of job does is its service's: app/services/calibration.py,
replay.py.

This package imports nothing itself: the store imports snapshot.py, and the runner imports the store.
"""
