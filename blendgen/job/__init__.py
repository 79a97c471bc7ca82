"""The job: a declarative YAML validated before any work starts."""

from blendgen.job.schema import Job, load_job  # noqa: F401
