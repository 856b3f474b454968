"""dynamixel"""
