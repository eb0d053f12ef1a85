def main() -> int:
    print("fgins")
    return 0
