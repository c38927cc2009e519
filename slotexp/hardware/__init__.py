"""Live runs on the robot (`slot hardware`): Algorithm 1 of the paper at the MPC rate.

One concept per module:

* ``config``   typed schemas for ``conf/hardware/`` and ``conf/odometry/`` and their checks
* ``xl430``    the XL430-W250 control table (addresses, sizes, units)
* ``mapping``  tendon angle <-> servo position, and the limits every command is clamped to
* ``bus``      the servo-bus interface and its dynamixel-sdk implementation
* ``portlock`` the serial port, claimed by one run at a time
* ``simbus``   the same interface backed by the simulator (hardware-in-the-loop)
* ``odometry`` state-estimate sources: ZeroMQ (VIO), MCAP replay, simulator
* ``timing``   deadline scheduling and loop-timing statistics
* ``slotexp.signals`` (not here) signal handling: Ctrl-C / SIGTERM / SIGHUP become a clean stop
* ``loop``     the control loop itself, identical for robot, emulator and simulator
* ``run``      wiring: open, check, warm up, loop, always torque off, log
* ``report``   metrics and figures from a hardware log (``slot figures``)

Nothing here is imported by the numerical core; ``dynamixel_sdk`` and ``zmq`` are
imported only where they are used.
"""
