"""End-to-end and cross-cutting tests: kills anywhere, resume, bit-reproducibility, Ray, Slurm, GPU, fuzzed inputs."""
