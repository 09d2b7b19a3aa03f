"""drivers/daq"""
