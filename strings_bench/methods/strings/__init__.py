"""STRinGS"""
