"""LinuxCNC 2.9 in the loop: a headless LinuxCNC machine from the axis config, every servo period.

`machine` writes the INI, HAL and parameter files of a 3-axis mill from the `nc:` section (limits,
travel, work offsets; the path tolerance becomes `G64 P Q`) with a simulated servo per joint (HAL
pid -> drive lag -> integrator), so LinuxCNC reports a real following error; `config/linuxcnc/`
holds the files for `config/axis_default.yaml`. `runner.run_program(program, nc=..., servo=...)`
runs one program in AUTO and returns a `samples.ServoTrace`: one row per 1 ms servo period (none
lost, counted from the servo thread's own tick counter), SI units, t = tick * period; commanded
position/velocity/acceleration, feedback, following error and PID output per joint, the program
line, and each period's CLOCK_MONOTONIC start time. `runner.LinuxcncRun` is the same as a context
manager that hands the rows out while the program runs. `check.linuxcnc_rejects` asks LinuxCNC's
stand-alone interpreter whether it accepts a program (and names the line it rejects).
Only one LinuxCNC runs per host: runs take an flock and wait for each other. As root, LinuxCNC
runs as the system user `feedtwin` (FEED_TWIN_LINUXCNC_USER), since rtapi_app refuses root.
Nothing here imports rclpy; `_display.py` is the program LinuxCNC itself starts (Debian's
Python, LinuxCNC's `linuxcnc` and `hal` modules).
"""
