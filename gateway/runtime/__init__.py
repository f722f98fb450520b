"""I/O helpers shared by the server, the simulator and the CLI (DESIGN section 1).

Wall-clock deadlines, the map store, trace writing and the process exit codes live here, below
every driver, so that no driver imports the CLI package.
"""
