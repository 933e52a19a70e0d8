"""Main control: the Cell and its ticker, and what every outside surface (the dashboard,
OPC UA, the part server) shares: operations on the cell, status snapshots, users, sessions,
the control token and access rules. May import: trees and every layer below.
"""
