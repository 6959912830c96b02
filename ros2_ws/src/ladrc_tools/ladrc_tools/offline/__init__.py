"""Offline tools on bags and headless runs: replay, report, CSV export, PID vs LADRC suite."""
