"""strings-bench: text readability benchmark for 3D Gaussian Splatting (reproduces STRinGS, WACV 2026)."""

__version__ = "0.1.0"
