"""drivers/serial"""
