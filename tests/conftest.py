"""Tests run as CI does: offline (Drake may open Meshcat on localhost, never download)."""

import os

os.environ["DRAKE_ALLOW_NETWORK"] = "meshcat"
os.environ.setdefault("MPLBACKEND", "Agg")
