"""DOConv restoration: data synthesis from proxy cameras, the network,
training and ablations (torch). (Contents arrive with the restoration issue.)
"""
