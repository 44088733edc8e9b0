"""The motion plan of a program: home, approach, passes, retract, links and return, each verified."""
