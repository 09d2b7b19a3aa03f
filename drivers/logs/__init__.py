"""drivers/logs"""
