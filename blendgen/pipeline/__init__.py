"""The whole pipeline: the supervisor (run.py), per-frame work in workers (frame.py), the job folder."""
