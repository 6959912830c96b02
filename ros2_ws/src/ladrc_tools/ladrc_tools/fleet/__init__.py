"""Fleet tools: many bags of many machines, on a distributed engine (docs/fleet.md)."""
