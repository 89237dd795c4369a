"""The robot and its rigid-body dynamics (Eqs. 1-2): Drake plant, regressor, base parameters, capsules.

The lowest stage: it imports only the shared base layer (``exceptions``, ``config``, ...).
"""
