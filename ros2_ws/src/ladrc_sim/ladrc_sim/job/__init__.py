"""The job world: a cutting job (sheet in XY, part program from DXF) and the CNC that runs it."""
