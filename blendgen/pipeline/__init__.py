"""The whole pipeline: the supervisor (run.py), per-frame work in workers (frame.py), the job folder,
the synthetic recording (synthetic.py) and `blendgen import` (import_command.py)."""
