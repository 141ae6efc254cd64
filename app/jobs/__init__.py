"""Background jobs, of any kind: the runner (runner.py: the jobs and their snapshots' versions, cancel, pause and
resume, the store), the two ways a job runs (thread_jobs.py: on a thread; process_jobs.py: in a worker process,
its payload built first, with its time limits), a job in memory and the context its code is given (job.py), the
worker processes (pool.py), the worker's side of a process job (worker.py: what runs in the spawned process,
light to import) and the snapshot every reader gets (snapshot.py: the store keeps it, the API answers it). What a
kind of job does is its service's: app/services/calibration.py, replay.py.

This package imports nothing itself: the store imports snapshot.py, and the runner imports the store.
"""
