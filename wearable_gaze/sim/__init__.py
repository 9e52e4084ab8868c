"""Synthetic stand-ins for the hardware: simulated view lines, and (issue 3) rendered sessions."""
